"""Refining a computation: finer settings, what they cost, and intervals that only shrink.

Every engine's ``lost_area_bounds`` is certified to contain the exact lost area,
so two computations of the same layer at different settings give two intervals
that both contain it: their **intersection** contains it too. Refining a layer
therefore never loses what the coarser run proved: :func:`merge_bounds` keeps
the tighter end of each side.

What "finer" means depends on the engine (:func:`refined_settings`):

* ``raster``: half the grid spacing h, and half the angular step when the nozzle
  turns. Its interval's width is about 2·h per mm of boundary plus ρ·Δφ per mm
  of the lost region's inner boundary (module :mod:`printability.mmc.raster`),
  so each step roughly halves it, for 4–16× the work.
* ``exact``: half the angular step when the nozzle turns (its width there is
  the angular margin δ = ρ·Δφ/2), otherwise twice the chords per quarter circle
  (its width is the chord error a·(1/κ − 1), κ = cos(3π/(8·quad_segs))).
* ``sampled`` and ``reference`` are not refined here (None).

:func:`refinement_work` estimates the work and memory of a computation before
it runs, so a refinement that would exceed ``Settings.max_memory`` or the work
budget is refused with the estimate instead of started.
"""

from __future__ import annotations

import math
from dataclasses import replace

import shapely
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError
from printability.mmc.result import MMCInternalError
from printability.model.geometry import Grid
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

__all__ = [
    "MAX_QUAD_SEGS",
    "MIN_ANGLE_STEP",
    "merge_bounds",
    "predicted_width",
    "refined_settings",
    "refinement_work",
]

#: Finest angular step a refinement goes to, degrees (Settings accepts 0.001).
MIN_ANGLE_STEP = 0.01
#: Most chords per quarter circle a refinement of the exact engine asks for.
MAX_QUAD_SEGS = 512

# seconds per unit of work (see printability.analysis.raster_work); the exact engine's unit
# is one boundary vertex at one angle at 32 chords per quarter circle, about 4 ms on the
# star of issue #26 (68 vertices, 0.43 s per angle): expressed in raster units
_EXACT_VERTEX_ANGLE = 4e-3 / 3e-9


def _angle_step(machine: Machine, settings: Settings) -> float:
    return float(settings.angle_step if settings.angle_step is not None else machine.angle_step)


def refined_settings(engine: str, nozzle: Nozzle, machine: Machine, settings: Settings,
                     ) -> Settings | None:
    """The settings of the next refinement of an ``engine`` computation, or None.

    Parameters
    ----------
    engine
        The engine that ran (``raster``, ``exact``; others are not refined).
    nozzle, machine
        The computation's nozzle and machine.
    settings
        The settings it ran with.

    Returns
    -------
    Settings or None
        Half the raster spacing (and half the angle step for a turning nozzle); for
        the exact engine half the angle step for a turning nozzle, else twice the
        chords per quarter circle; None when nothing finer is possible or the engine
        is not refined here.
    """
    turns = machine.turns(nozzle) and len(machine.angles(
        step=settings.angle_step, period=nozzle.symmetry_period)) > 1
    step = _angle_step(machine, settings) if turns else None
    finer_step = step / 2 if step is not None and step / 2 >= MIN_ANGLE_STEP else None
    if engine == "raster":
        h = settings.resolution / 2
        if h < 1e-5:
            return None
        return replace(settings, resolution=h,
                       angle_step=finer_step if finer_step is not None else settings.angle_step)
    if engine == "exact":
        if finer_step is not None:
            return replace(settings, angle_step=finer_step)
        if settings.quad_segs * 2 <= MAX_QUAD_SEGS:
            return replace(settings, quad_segs=settings.quad_segs * 2)
        return None
    return None


def refinement_work(region: BaseGeometry, nozzle: Nozzle, machine: Machine, engine: str,
                    settings: Settings) -> tuple[float, int]:
    """Estimated (work, peak memory in bytes) of a computation, before it runs.

    Work is in the units of :func:`printability.analysis.raster_work` (about 3 ns
    each on one core). Raster: cells × angles × kernel words, memory from
    :func:`printability.mmc._raster_prepare.estimate_memory` with every word
    varying (the worst case). Exact: boundary vertices × angles × quad_segs/32;
    memory is small (vector geometry) and counted as 0. Other engines: (0, 0).
    """
    if engine == "raster":
        from printability.analysis import raster_work
        from printability.mmc._raster_prepare import estimate_memory, kernel_radius

        work, parts = raster_work(region.bounds, nozzle, machine, settings)
        step = settings.angle_step
        angles = machine.angles(step=step, period=nozzle.symmetry_period)
        gap = _angle_step(machine, settings) if len(angles) > 1 else 0.0
        delta = nozzle.radius * math.radians(gap) / 2.0
        radius = kernel_radius(nozzle, settings.resolution, delta, settings.quad_segs)
        grid = Grid(0.0, 0.0, settings.resolution, max(parts["nx"], 1), max(parts["ny"], 1))
        return work, estimate_memory(grid, len(angles), radius, band_words=None)
    if engine == "exact":
        n_angles = len(machine.angles(step=settings.angle_step, period=nozzle.symmetry_period))
        vertices = shapely.get_num_coordinates(region)
        return (float(vertices) * n_angles * settings.quad_segs / 32 * _EXACT_VERTEX_ANGLE, 0)
    return 0.0, 0


def predicted_width(width: float, engine: str, steps: int) -> float:
    """The interval width expected after ``steps`` refinements of one that is ``width`` now.

    Both engines' widths shrink about linearly with the step refined (h, Δφ) for the
    raster and the rotary exact engine, so half per step; the exact engine's chord
    error shrinks as quad_segs⁻², but its width is rarely what a tolerance waits on,
    so the same (cautious) half is used. Other engines do not refine: unchanged.
    """
    if steps < 0:
        raise InputError(f"refinement steps must be ≥ 0; got {steps}")
    if engine not in ("raster", "exact"):
        return width
    return width / 2.0 ** steps


def merge_bounds(old: tuple[float, float], new: tuple[float, float], *, target_area: float,
                 ) -> tuple[float, float]:
    """The intersection of two certified intervals of the same lost area.

    Both contain the exact value, so their intersection does. Each engine widens its
    interval by 10⁻⁹·λ(G) for rounding; intervals that miss each other by less than
    that meet at their midpoint.

    Raises
    ------
    MMCInternalError
        When they miss each other by more: one of the two engines broke its guarantee.
    """
    lo = max(old[0], new[0])
    hi = min(old[1], new[1])
    if lo > hi:
        slack = 2e-9 * max(target_area, 1e-12) + 1e-15
        if lo - hi > slack:
            raise MMCInternalError(
                f"two computations of one layer certify disjoint lost-area intervals "
                f"[{old[0]!r}, {old[1]!r}] and [{new[0]!r}, {new[1]!r}] mm²: one of them is "
                "wrong. This is a bug: please report it with the input.")
        lo = hi = 0.5 * (lo + hi)
    return lo, hi
