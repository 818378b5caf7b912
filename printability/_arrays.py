"""Moved to :mod:`printability.base.arrays` (issue #25); this module re-exports it so old
imports keep working. New code imports ``printability.base.arrays``."""

from __future__ import annotations

from printability.base.arrays import *  # noqa: F403
from printability.base.arrays import __all__ as __all__
from printability.base.arrays import (  # noqa: F401
    take_rows,
)
