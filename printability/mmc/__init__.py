"""MMC engines: the motion restriction P, the as-built layer S and what is lost.

Every engine is a plain function ``f(region, nozzle, machine, *, settings) ->
MMCResult``; :func:`compute_mmc` validates the inputs and dispatches by the
names of :data:`printability.options.ENGINES`. Engines are imported lazily so
that importing printability stays cheap (numba compiles on first use).
"""

from __future__ import annotations

import importlib
from typing import Any

import shapely

from printability.errors import InputError, NozzleTooLargeError
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.model.geometry import as_region
from printability.model.machine import Machine, parse_machine
from printability.model.nozzle import Nozzle, parse_nozzle
from printability.options import ENGINES
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "EXACT_VERTEX_LIMIT",
    "Components",
    "MMCResult",
    "MotionRestriction",
    "choose_engine",
    "compute_mmc",
]

# name -> "module:function"; every name of ENGINES but "auto" must be here (tested).
ENGINE_FUNCTIONS: dict[str, str] = {
    "exact": "printability.mmc.exact:mmc_exact",
    "raster": "printability.mmc.raster:mmc_raster",
    "reference": "printability.mmc.reference:mmc_reference",
    "sampled": "printability.mmc.sampled:mmc_sampled",
}


# Above this many boundary vertices the exact engine's certified offsets and unions cost
# minutes per layer (an 18k-vertex G-code layer: 144 s exact, 3 s raster), so auto prefers
# the raster engine, whose cost follows the area, not the vertex count.
EXACT_VERTEX_LIMIT = 10_000


def choose_engine(nozzle: Nozzle, machine: Machine, region: Any = None) -> str:
    """The engine ``auto`` picks.

    Chains need the sampled engine; a nozzle that does not turn (XY machine,
    or a round nozzle on any separable machine) is exact in vector form unless
    the region has more than :data:`EXACT_VERTEX_LIMIT` vertices; an
    asymmetric nozzle on a rotary axis goes to the raster engine, whose cost
    does not grow with the number of polygon vertices.
    """
    if not machine.separable:
        return "sampled"
    if not machine.turns(nozzle):
        if region is not None and shapely.get_num_coordinates(region) > EXACT_VERTEX_LIMIT:
            return "raster"
        return "exact"
    return "raster"


def compute_mmc(
    region: Any,
    nozzle: str | Nozzle,
    machine: str | Machine = "xy",
    *,
    engine: str = "auto",
    settings: Settings = DEFAULT_SETTINGS,
    name: str = "region",
) -> MMCResult:
    """Compute the MMC restriction and the as-built layer of one region.

    Parameters
    ----------
    region
        The layer target G (shapely geometry; validated by ``as_region``).
    nozzle, machine
        Objects or SPEC strings (``"ellipse:major=0.8,minor=0.3"``, ``"ttr"``).
    engine
        One of :data:`printability.options.ENGINES`.
    settings
        Tolerances and limits.
    name
        How the region is named in error messages.

    Raises
    ------
    UnknownOptionError, InputError, ResourceError
        Before any heavy work.
    """
    engine = ENGINES.check(engine)
    noz = parse_nozzle(nozzle)
    mach = parse_machine(machine)
    g = as_region(region, name=name)
    if noz.area > g.area:
        raise NozzleTooLargeError(
            f"{name}: the nozzle {noz.spec!r} ({noz.area:.4g} mm²) is larger than the region "
            f"({g.area:.4g} mm²); it cannot fit anywhere, so nothing of it would be printed"
        )
    if engine == "auto":
        engine = choose_engine(noz, mach, g)
    if engine in ("exact", "raster", "reference") and not mach.separable:
        raise InputError(
            f"the {engine} engine needs a separable machine (xy or ttr); machine "
            f"{mach.name!r} is a joint chain: use engine='sampled' or 'auto'"
        )
    module, func = ENGINE_FUNCTIONS[engine].split(":")
    fn = getattr(importlib.import_module(module), func)
    return fn(g, noz, mach, settings=settings)
