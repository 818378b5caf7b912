"""Moved to :mod:`printability.base.settings` (issue #25); this module re-exports it so old
imports keep working. New code imports ``printability.base.settings``."""

from __future__ import annotations

from printability.base.settings import *  # noqa: F403
from printability.base.settings import (  # noqa: F401
    DEFAULT_SETTINGS,
    Settings,
    default_memory_limit,
)
from printability.base.settings import __all__ as __all__
