"""Moved to :mod:`printability.base.options` (issue #25); this module re-exports it so old
imports keep working. New code imports ``printability.base.options``."""

from __future__ import annotations

from printability.base.options import *  # noqa: F403
from printability.base.options import (  # noqa: F401
    BEAD_MODELS,
    CORNER_PIECES,
    E_POLICIES,
    ENDSTOP_POLICIES,
    ENGINES,
    EXTRUDER_ERROR_POLICIES,
    FAULT_KINDS,
    FEED_POLICIES,
    FIRMWARE_PROFILES,
    FLAVORS,
    JOINT_KINDS,
    MACHINE_KINDS,
    NOZZLE_KINDS,
    REGISTRIES,
    SERVER_POLICIES,
    SIM_CLOCKS,
    SOURCE_FORMATS,
    STREAM_MODES,
    UNITS,
    Registry,
)
from printability.base.options import __all__ as __all__
