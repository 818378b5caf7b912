"""Moved to :mod:`printability.base.kernel_cache` (issue #25); this module re-exports it so
old imports keep working."""

from __future__ import annotations

from printability.base.kernel_cache import *  # noqa: F403
from printability.base.kernel_cache import (  # noqa: F401
    KERNEL_MODULES,
    announce_first_compile,
    check,
    ensure_checked,
    guard,
)
from printability.base.kernel_cache import __all__ as __all__
