"""Frozen numerical settings that travel with every computation.

There are no global mutable settings in printability: functions take a
``settings: Settings`` keyword argument (default :data:`DEFAULT_SETTINGS`) and
derive variants with :func:`dataclasses.replace`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

from printability.base.errors import InputError

__all__ = ["DEFAULT_SETTINGS", "Settings", "default_memory_limit"]


def default_memory_limit() -> int:
    """Half the physical memory, in bytes (at most 16 GiB); 4 GiB when unknown."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 4 << 30
    return int(min(total // 2, 16 << 30))


@dataclass(frozen=True)
class Settings:
    """Tolerances and limits of a computation.

    Attributes
    ----------
    resolution
        Raster grid spacing h, mm.
    angle_step
        Angular sampling step for rotary axes, degrees; ``None`` uses the
        machine's own step.
    quad_segs
        Segments per quarter circle when a circle/ellipse is approximated by a
        polygon in the vector engines. The chord error for radius r is
        r·(1 − cos(π/(4·quad_segs))).
    area_tolerance
        Absolute area below which a piece of geometry is treated as empty, mm².
    chord_tolerance
        Maximum distance between an arc and its linearisation, mm.
    max_memory
        Largest working set a computation may allocate, bytes. Estimated
        before any big allocation; beyond it a ResourceError is raised.
    workers
        Parallel worker processes for per-layer work (1 = in-process).
    progress
        Show progress bars on stderr.
    """

    resolution: float = 0.05
    angle_step: float | None = None
    quad_segs: int = 32
    area_tolerance: float = 1e-9
    chord_tolerance: float = 0.002
    max_memory: int = field(default_factory=default_memory_limit)
    workers: int = 1
    progress: bool = False

    def __post_init__(self) -> None:
        if not (self.resolution > 0):
            raise InputError(f"resolution must be a positive length in mm; got {self.resolution!r}")
        if not (self.resolution < 1e4):
            raise InputError(f"resolution must be a finite length below 10 m; got "
                             f"{self.resolution!r}")
        if self.angle_step is not None and not (1e-3 <= self.angle_step <= 360):
            raise InputError(
                f"angle_step must be in [0.001, 360] degrees; got {self.angle_step!r}"
            )
        if self.quad_segs < 1:
            raise InputError(f"quad_segs must be at least 1; got {self.quad_segs!r}")
        if not (0 < self.max_memory <= 1 << 50):
            raise InputError(f"max_memory must be positive and at most 1 PiB; got "
                             f"{self.max_memory!r}")
        if self.workers < 1:
            raise InputError(f"workers must be at least 1; got {self.workers!r}")

    def with_(self, **changes: object) -> Settings:
        """Return a copy with some fields changed (validated again)."""
        return replace(self, **changes)


DEFAULT_SETTINGS = Settings()
