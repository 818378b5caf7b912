"""Moved to :mod:`printability.base.errors` (issue #25); this module re-exports it so old
imports keep working. New code imports ``printability.base.errors``."""

from __future__ import annotations

from printability.base.errors import *  # noqa: F403
from printability.base.errors import (  # noqa: F401
    EXCERPT_LENGTH,
    FileFormatError,
    InputError,
    NozzleTooLargeError,
    PrintabilityError,
    PrintabilityOSError,
    PrinterError,
    ResourceError,
    StoppedError,
    UnknownOptionError,
    excerpt,
)
from printability.base.errors import __all__ as __all__
