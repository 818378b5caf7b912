"""How much work a layer × nozzle asks of the raster engine, and the guard that refuses too much.

:func:`raster_work` estimates the engine's work on a region before it starts;
:func:`check_raster_work` refuses, before any engine runs, a layer × nozzle of an
analysis that would take far too long, and names a resolution that fits.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from printability.errors import ResourceError
from printability.mmc import choose_engine
from printability.model.layers import LayerStack
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

__all__ = ["RASTER_WORK_BUDGET", "SECONDS_PER_WORK", "check_raster_work", "raster_work"]

RASTER_WORK_BUDGET = 5e10
"""Most work (see :func:`raster_work`) one layer × nozzle may ask of the raster engine:
one to three minutes on one core. The memory it would take is checked by the engine itself
(``Settings.max_memory``); this bounds the time, which grows as resolution⁻³."""

# Seconds per unit of raster_work, measured on an ellipse nozzle over a 10 mm square, T-T-R:
# 1.7e10 in 25 s at 2 µm, 3.9e10 in 51 s at 1.5 µm, 1.3e11 in 404 s at 1 µm (finer grids run
# slower per unit, out of cache); the slow end, so the minutes said are not optimistic.
SECONDS_PER_WORK = 3e-9


def raster_work(bounds: Sequence[float], nozzle: Nozzle, machine: Machine,
                settings: Settings) -> tuple[float, dict[str, Any]]:
    """Estimate the raster engine's work on a region, before it starts.

    The engine sweeps every cell of its grid at every sampled angle with the
    nozzle's kernel, one 64-cell word at a time per kernel row: work is
    cells × angles × max(1, kernel width / 64), the kernel being 2·radius/h + 1
    cells wide. So it grows as resolution⁻³ once the kernel is wider than a word.

    Parameters
    ----------
    bounds
        ``(minx, miny, maxx, maxy)`` of the region, mm.
    nozzle, machine, settings
        As for the engine (``settings.resolution``, ``settings.angle_step``).

    Returns
    -------
    work, parts
        The estimate, and what it is made of (``nx``, ``ny``, ``angles``, ``kernel``).
    """
    h = settings.resolution
    n_angles = len(machine.angles(step=settings.angle_step, period=nozzle.symmetry_period))
    margin = nozzle.radius + 2 * h
    minx, miny, maxx, maxy = bounds
    nx = math.ceil((maxx - minx + 2 * margin) / h) + 1
    ny = math.ceil((maxy - miny + 2 * margin) / h) + 1
    kernel = 2 * math.ceil(nozzle.radius / h + 2) + 1
    work = float(nx) * ny * n_angles * max(1.0, kernel / 64)
    return work, {"nx": nx, "ny": ny, "angles": n_angles, "kernel": kernel}


def _nice_up(x: float) -> float:
    """The smallest of 1, 2, 2.5, 5 × 10^k that is at least ``x``."""
    k = math.floor(math.log10(x))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if m * 10**k >= x * (1 - 1e-9):
            return m * 10**k
    return 10.0 ** (k + 1)  # pragma: no cover - the loop ends at 10


def check_raster_work(layers: LayerStack, nozzles: Sequence[Nozzle], machine: Machine,
                      engine: str, settings: Settings, budget: float) -> None:
    """Refuse, before any engine runs, a layer × nozzle the raster engine would take far
    too long over (see :func:`raster_work`); the message gives the estimate, its parts and
    a resolution that fits."""
    for noz in nozzles:
        for layer in layers:
            eng = choose_engine(noz, machine, layer.region) if engine == "auto" else engine
            if eng != "raster":
                continue
            work, parts = raster_work(layer.region.bounds, noz, machine, settings)
            if work <= budget:
                continue
            h = settings.resolution
            # work ∝ h⁻² (cells), h⁻³ once the kernel is wider than a word
            ratio = work / budget
            coarser = _nice_up(h * ratio ** (1 / 3 if parts["kernel"] > 64 else 1 / 2))
            while raster_work(layer.region.bounds, noz, machine,
                              replace(settings, resolution=coarser))[0] > budget:
                coarser = _nice_up(coarser * 1.01)
            minutes = work * SECONDS_PER_WORK / 60
            raise ResourceError(
                f"{layers.source or 'the input'}, layer {layer.index} (z={layer.z:g} mm), "
                f"nozzle {noz.spec}: the raster engine would do about {work:.2g} operations "
                f"(a {parts['nx']:,} × {parts['ny']:,} grid at --resolution {h:g} mm, × "
                f"{parts['angles']} angle(s), × a nozzle kernel {parts['kernel']} cells wide), "
                f"roughly {minutes:,.0f} minutes, more than the {budget:.2g} allowed "
                f"(a few minutes); nothing was computed. Use --resolution {coarser:g} or "
                f"coarser" + (", or a larger --angle-step" if parts["angles"] > 1 else ""))
