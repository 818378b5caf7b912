"""Analyse a sliced part for several nozzles on one machine: per layer, per nozzle.

:func:`analyze` runs :func:`printability.mmc.compute_mmc` on every layer of a
:class:`~printability.layers.LayerStack` for every candidate nozzle, sums
areas and volumes, ranks the nozzles (:mod:`printability.ranking`) and returns
an immutable :class:`Analysis` whose :meth:`Analysis.to_json` is the JSON
contract of DESIGN.md §4.

Layers are independent, so they run in parallel: ``settings.workers``
processes on this machine, or a Dask cluster when ``scheduler`` names one
(the ``dask`` extra).
"""

from __future__ import annotations

import math
import multiprocessing
import multiprocessing.context
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

from printability import __version__
from printability.errors import (
    InputError,
    NozzleTooLargeError,
    PrintabilityOSError,
    ResourceError,
)
from printability.layers import Layer, LayerStack
from printability.machine import Machine, parse_machine
from printability.mmc import MMCResult, choose_engine, compute_mmc
from printability.nozzle import Nozzle, parse_nozzle
from printability.options import ENGINES
from printability.ranking import Totals, certified_ranks, ties, totals, uses_volume
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = ["DEFAULT_REFINE_BUDGET", "MAX_REFINE_ROUNDS", "RASTER_WORK_BUDGET", "Analysis",
           "BoundTolerance", "LayerOutcome", "NozzleAnalysis", "Refinement", "analyze",
           "raster_work", "select_layers"]


@dataclass(frozen=True)
class LayerOutcome:
    """One nozzle on one layer.

    ``result`` is the full engine result (None when the nozzle fits nowhere in
    the layer, in which case the whole layer is lost, or when results were
    not kept).
    """

    index: int
    z: float
    height: float
    target_area: float
    as_built_area: float
    lost_area: float
    lost_area_bounds: tuple[float, float]
    components: int
    engine: str
    elapsed: float
    result: MMCResult | None = field(default=None, compare=False, repr=False)
    note: str = ""
    resolution: float = 0.0
    angle_step: float = 0.0
    refinements: int = 0

    @property
    def width(self) -> float:
        """hi − lo of the certified lost-area interval, mm²."""
        return self.lost_area_bounds[1] - self.lost_area_bounds[0]

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "z": self.z,
            "height": self.height,
            "target_area": self.target_area,
            "as_built_area": self.as_built_area,
            "lost_area": self.lost_area,
            "lost_area_bounds": list(self.lost_area_bounds),
            "components": self.components,
            "engine": self.engine,
            **({"resolution": self.resolution} if self.resolution else {}),
            **({"angle_step": self.angle_step} if self.angle_step else {}),
            **({"refinements": self.refinements} if self.refinements else {}),
            **({"note": self.note} if self.note else {}),
        }


@dataclass(frozen=True)
class NozzleAnalysis:
    """One nozzle over all layers; areas in mm², volumes in mm³ (Σ area·height).

    ``rank`` is the place in the list (by estimate); ``rank_range`` the ranks the
    certified bounds allow and ``tied_with`` the nozzles whose interval overlaps
    this one's (:mod:`printability.ranking`). ``allowed_width`` is the width hi − lo
    a ``bound_tolerance`` asked for (in the unit of :meth:`totals`), None without one.
    """

    nozzle: Nozzle
    layers: tuple[LayerOutcome, ...]
    rank: int = 0
    build_time: float = 0.0
    rank_range: tuple[int, int] = (0, 0)
    tied_with: tuple[str, ...] = ()
    allowed_width: float | None = None

    def totals(self, *, volume: bool | None = None) -> Totals:
        """Target, lost and bounds in one unit (:func:`printability.ranking.totals`)."""
        return totals(self.layers, volume=volume)

    @property
    def tolerance_met(self) -> bool | None:
        """Whether hi − lo is within ``allowed_width`` (None without a tolerance)."""
        if self.allowed_width is None:
            return None
        lo, hi = self.totals().lost_bounds
        return hi - lo <= self.allowed_width * (1 + 1e-12)

    @property
    def target_area(self) -> float:
        return sum(o.target_area for o in self.layers)

    @property
    def as_built_area(self) -> float:
        return sum(o.as_built_area for o in self.layers)

    @property
    def lost_area(self) -> float:
        return sum(o.lost_area for o in self.layers)

    @property
    def lost_area_bounds(self) -> tuple[float, float]:
        return (sum(o.lost_area_bounds[0] for o in self.layers),
                sum(o.lost_area_bounds[1] for o in self.layers))

    @property
    def lost_fraction(self) -> float:
        t = self.target_area
        return self.lost_area / t if t > 0 else 0.0

    @property
    def components(self) -> int:
        """Largest number of configuration-space components in any layer."""
        return max((o.components for o in self.layers), default=0)

    def volume(self, what: str) -> float:
        """Σ over layers of an area attribute times the layer height, mm³."""
        return sum(getattr(o, what) * o.height for o in self.layers)

    def to_json(self, *, multi_layer: bool) -> dict[str, Any]:
        out: dict[str, Any] = {
            "spec": self.nozzle.spec,
            "rank": self.rank,
            "rank_range": list(self.rank_range),
            "rank_certain": self.rank_range[0] == self.rank_range[1],
            "tied_with": list(self.tied_with),
            "target_area": self.target_area,
            "as_built_area": self.as_built_area,
            "lost_area": self.lost_area,
            "lost_fraction": self.lost_fraction,
            "lost_area_bounds": list(self.lost_area_bounds),
            "components": self.components,
            "build_time_estimate_s": self.build_time,
            "layers": [o.to_json() for o in self.layers],
        }
        if multi_layer:
            vol = totals(self.layers, volume=True)
            out.update(
                target_volume=self.volume("target_area"),
                as_built_volume=self.volume("as_built_area"),
                lost_volume=self.volume("lost_area"),
                lost_volume_bounds=list(vol.lost_bounds),
            )
        if self.allowed_width is not None:
            t = self.totals()
            out["bound_tolerance"] = {
                "quantity": t.quantity, "unit": t.unit, "allowed_width": self.allowed_width,
                "width": t.lost_bounds[1] - t.lost_bounds[0], "met": self.tolerance_met}
        return out


@dataclass(frozen=True)
class Analysis:
    """A ranked analysis of one part: ``nozzles`` sorted by rank (best first)."""

    input: str
    machine: Machine
    engine: str
    settings: Settings
    layers: LayerStack
    nozzles: tuple[NozzleAnalysis, ...]
    elapsed: float
    refinement: Refinement | None = None

    @property
    def multi_layer(self) -> bool:
        return len(self.layers) > 1

    @property
    def quantity(self) -> str:
        """``"volume"`` (mm³) or ``"area"`` (mm²): what the ranking compares."""
        return "volume" if uses_volume([lay.height for lay in self.layers]) else "area"

    @property
    def ties(self) -> tuple[tuple[str, str], ...]:
        """Pairs of nozzle SPECs whose certified intervals overlap: not ranked for sure."""
        vol = self.quantity == "volume"
        b = [n.totals(volume=vol).lost_bounds for n in self.nozzles]
        return tuple((self.nozzles[i].nozzle.spec, self.nozzles[j].nozzle.spec)
                     for i, j in ties(b))

    def to_json(self) -> dict[str, Any]:
        """The JSON document of DESIGN.md §4 (plain dicts, lists and floats)."""
        return {
            "input": self.input,
            "units": "mm",
            "version": __version__,
            "machine": self.machine.spec,
            "engine": self.engine,
            "resolution": self.settings.resolution,
            "layers": len(self.layers),
            **({"selected_layers": self.layers.meta["selected_layers"]}
               if "selected_layers" in self.layers.meta else {}),
            "elapsed_s": self.elapsed,
            "ranking": {
                "quantity": self.quantity,
                "unit": "mm³" if self.quantity == "volume" else "mm²",
                "certain": not self.ties,
                "ties": [list(t) for t in self.ties],
            },
            **({"refinement": self.refinement.to_json()} if self.refinement is not None else {}),
            "nozzles": [n.to_json(multi_layer=self.multi_layer) for n in self.nozzles],
        }


DEFAULT_REFINE_BUDGET = 4.0
"""Work tie separation may add, as a multiple of the first pass's estimated work."""

MAX_REFINE_ROUNDS = 8
"""Most refinement rounds of :func:`analyze` (each halves the step of the layers it refines)."""


RASTER_WORK_BUDGET = 5e10
"""Most work (see :func:`raster_work`) one layer × nozzle may ask of the raster engine:
one to three minutes on one core. The memory it would take is checked by the engine itself
(``Settings.max_memory``); this bounds the time, which grows as resolution⁻³."""

# Seconds per unit of raster_work, measured on an ellipse nozzle over a 10 mm square, T-T-R:
# 1.7e10 in 25 s at 2 µm, 3.9e10 in 51 s at 1.5 µm, 1.3e11 in 404 s at 1 µm (finer grids run
# slower per unit, out of cache); the slow end, so the minutes said are not optimistic.
_SECONDS_PER_WORK = 3e-9


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


def _check_raster_work(layers: LayerStack, nozzles: Sequence[Nozzle], machine: Machine,
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
            minutes = work * _SECONDS_PER_WORK / 60
            raise ResourceError(
                f"{layers.source or 'the input'}, layer {layer.index} (z={layer.z:g} mm), "
                f"nozzle {noz.spec}: the raster engine would do about {work:.2g} operations "
                f"(a {parts['nx']:,} × {parts['ny']:,} grid at --resolution {h:g} mm, × "
                f"{parts['angles']} angle(s), × a nozzle kernel {parts['kernel']} cells wide), "
                f"roughly {minutes:,.0f} minutes, more than the {budget:.2g} allowed "
                f"(a few minutes); nothing was computed. Use --resolution {coarser:g} or "
                f"coarser" + (", or a larger --angle-step" if parts["angles"] > 1 else ""))


SCHEDULER_TIMEOUT = "20s"
"""How long to wait for a Dask scheduler to answer before giving up."""


def select_layers(layers: LayerStack, spec: str) -> LayerStack:
    """Keep some layers of a stack, by 0-based index.

    Parameters
    ----------
    layers
        The part.
    spec
        Comma-separated items, each an index ``7``, an inclusive range ``3-9`` or a
        Python-style slice ``START:STOP[:STEP]`` (ends may be omitted, ``::10`` is
        every tenth layer). Negative indices count from the top.

    Returns
    -------
    LayerStack
        The chosen layers in z order, renumbered from 0; each keeps its index in
        the full stack as ``meta["source_index"]``.

    Raises
    ------
    InputError
        The spec cannot be read or selects no layer.
    """
    n = len(layers)
    chosen: set[int] = set()

    def bad(why: str) -> InputError:
        return InputError(f"--layers {spec!r}: {why}; expected indices, ranges A-B or slices "
                          f"START:STOP:STEP of the {n} layer(s) of {layers.source or 'the input'}"
                          f" (0 is the bottom layer)")

    def num(v: str, item: str) -> int:
        try:
            return int(v)
        except ValueError:
            raise bad(f"{item!r} is not a number, range or slice") from None

    def check(i: int) -> int:
        if not -n <= i < n:
            raise bad(f"layer {i} does not exist")
        return i % n

    for item in (t.strip() for t in spec.split(",")):
        if ":" in item:
            parts = [num(v, item) if v.strip() else None for v in item.split(":")]
            if len(parts) > 3 or (len(parts) == 3 and parts[2] == 0):
                raise bad(f"{item!r} is not a slice")
            chosen.update(range(n)[slice(*parts)])
        elif "-" in item.lstrip("-"):
            a, b = item.lstrip("-").split("-", 1)
            lo = check(-num(a, item) if item.startswith("-") else num(a, item))
            chosen.update(range(lo, check(num(b, item)) + 1))
        else:
            chosen.add(check(num(item, item)))
    if not chosen:
        raise bad("no layer selected")
    kept = tuple(replace(layers[i], index=k, meta={**layers[i].meta, "source_index": i})
                 for k, i in enumerate(sorted(chosen)))
    return replace(layers, layers=kept, meta={**layers.meta, "selected_layers": sorted(chosen)})


def _outcome(layer: Layer, nozzle: Nozzle, machine: Machine, engine: str,
             settings: Settings, keep: bool) -> LayerOutcome:
    t0 = time.perf_counter()
    area = layer.area
    eng = choose_engine(nozzle, machine, layer.region) if engine == "auto" else engine
    try:
        r = compute_mmc(layer.region, nozzle, machine, engine=eng, settings=settings,
                        name=f"layer {layer.index} (z={layer.z:g} mm)")
    except NozzleTooLargeError:
        return LayerOutcome(layer.index, layer.z, layer.height, area, 0.0, area, (area, area), 0,
                            eng, time.perf_counter() - t0, None,
                            note="nozzle larger than the layer: nothing printable")
    return LayerOutcome(layer.index, layer.z, layer.height, r.target_area, r.as_built_area,
                        r.lost_area, (float(r.lost_area_bounds[0]), float(r.lost_area_bounds[1])),
                        r.components.count, r.engine, r.elapsed, r if keep else None,
                        resolution=float(r.resolution), angle_step=float(r.angle_step))


def _run_task(args: tuple) -> LayerOutcome:
    return _outcome(*args)


def analyze(
    layers: LayerStack,
    nozzles: Sequence[str | Nozzle],
    machine: str | Machine = "xy",
    *,
    engine: str = "auto",
    settings: Settings = DEFAULT_SETTINGS,
    keep_results: bool = True,
    scheduler: str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    max_raster_work: float = RASTER_WORK_BUDGET,
    bound_tolerance: BoundTolerance | str | float | None = None,
    separate_ties: bool = False,
    refine_budget: float = DEFAULT_REFINE_BUDGET,
    max_rounds: int = MAX_REFINE_ROUNDS,
) -> Analysis:
    """Analyse every layer for every nozzle and rank the nozzles.

    Parameters
    ----------
    layers
        The part (see :func:`printability.sources.load_layers`).
    nozzles
        Candidate nozzle SPECs or objects; at least one.
    machine
        Machine SPEC or object.
    engine
        One of :data:`printability.options.ENGINES`.
    settings
        Tolerances; ``settings.workers`` > 1 runs layers in parallel processes.
    keep_results
        Keep every engine result (geometry for the report); turn off for big
        parts to bound memory.
    scheduler
        Address of a Dask scheduler (``tcp://host:port``) to run the layers on
        a cluster instead of local processes (needs the ``dask`` extra).
    on_progress
        Called with (done, total) after each layer×nozzle task.
    max_raster_work
        Most work a layer × nozzle may ask of the raster engine (see
        :func:`raster_work`); checked for every task before any runs, and for
        every refinement before it runs.
    bound_tolerance
        Refine until every nozzle's certified interval of what it loses over the
        part (mm² for one layer, mm³ for several: the ranking's unit) is at most
        this wide: a :class:`BoundTolerance` or its text (``"0.5"`` absolute,
        ``"5%"`` relative). None: no such goal.
    separate_ties
        Refine the nozzles whose certified intervals overlap until they separate,
        within ``refine_budget``.
    refine_budget
        Most work tie separation may add, as a multiple of the first pass's
        estimated work (a tolerance is not limited by it, only by the memory and
        work guards).
    max_rounds
        Most refinement rounds (each refines some layers of some nozzles once).

    Returns
    -------
    Analysis
        Nozzles listed by lost area (volume for several layers), near-equal
        estimates ordered by the build-time estimate; each with the ranks its
        certified bounds allow. ``refinement`` says what refinement did and cost.

    Raises
    ------
    ResourceError
        A layer × nozzle would take the raster engine more than ``max_raster_work``
        (the message gives the estimate and a resolution that fits), or meeting
        ``bound_tolerance`` would need more memory or work than allowed (refused
        with the estimate before the refinement runs).
    """
    engine = ENGINES.check(engine)
    if not nozzles:
        raise InputError("analyze: give at least one nozzle (e.g. --nozzle circle:d=0.4)")
    nozs = [parse_nozzle(n) for n in nozzles]
    mach = parse_machine(machine)
    tol = BoundTolerance.parse(bound_tolerance) if bound_tolerance is not None else None
    if not (refine_budget >= 0 and math.isfinite(refine_budget)):
        raise InputError(f"analyze: refine_budget must be a finite number ≥ 0; got "
                         f"{refine_budget!r}")
    _check_raster_work(layers, nozs, mach, engine, settings, max_raster_work)
    if tol is not None and not tol.relative:
        _precheck_tolerance(layers, nozs, mach, engine, settings, tol, max_raster_work)
    t0 = time.perf_counter()
    tasks = [(layer, noz, mach, engine, settings, keep_results) for noz in nozs for layer in layers]
    outcomes = list(_map(tasks, settings=settings, scheduler=scheduler, on_progress=on_progress))
    per_nozzle = []
    n_layers = len(layers)
    for i, noz in enumerate(nozs):
        per_nozzle.append(NozzleAnalysis(noz, tuple(outcomes[i * n_layers:(i + 1) * n_layers])))
    refinement = None
    if tol is not None or separate_ties:
        per_nozzle, refinement = _refine(
            per_nozzle, layers, mach, settings, tol=tol, separate=separate_ties,
            budget=refine_budget, max_rounds=max_rounds, max_work=max_raster_work,
            keep=keep_results, scheduler=scheduler, on_progress=on_progress)
    ranked = _rank(per_nozzle, mach, layers)
    used = {o.engine for n in ranked for o in n.layers}
    return Analysis(
        input=layers.source,
        machine=mach,
        engine=used.pop() if len(used) == 1 else "mixed",
        settings=settings,
        layers=layers,
        nozzles=tuple(ranked),
        elapsed=time.perf_counter() - t0,
        refinement=refinement,
    )


def _rank(per_nozzle: list[NozzleAnalysis], machine: Machine, layers: LayerStack,
          ) -> list[NozzleAnalysis]:
    """Order by the estimate in the ranking's unit; certified rank ranges and ties."""
    from printability.ranking import DEFAULT_SPEED, bead_width_for_time, rank_order

    volume = uses_volume([lay.height for lay in layers])
    timed = []
    for n in per_nozzle:
        w = bead_width_for_time(n.nozzle, rotary=machine.has_rotary and not n.nozzle.is_round)
        timed.append(replace(n, build_time=n.as_built_area / (w * DEFAULT_SPEED)))
    tots = [n.totals(volume=volume) for n in timed]
    order = rank_order([t.lost for t in tots], [n.build_time for n in timed])
    bounds = [t.lost_bounds for t in tots]
    ranges = certified_ranks(bounds)
    tied: dict[int, list[str]] = {i: [] for i in range(len(timed))}
    for i, j in ties(bounds):
        tied[i].append(timed[j].nozzle.spec)
        tied[j].append(timed[i].nozzle.spec)
    return [replace(timed[i], rank=k + 1, rank_range=ranges[i], tied_with=tuple(tied[i]))
            for k, i in enumerate(order)]


# --------------------------------------------------------------------------- refinement

@dataclass(frozen=True)
class BoundTolerance:
    """How wide a nozzle's certified interval of lost material may be, over the part.

    Attributes
    ----------
    value
        Absolute: the width hi − lo in the ranking's unit (mm² for one layer, mm³
        for several). Relative: a fraction r of the estimated lost amount, with a
        floor of r/100 of the part's size (so ``5%`` allows 5 % of the loss or
        0.05 % of the part, whichever is larger: a part that loses almost nothing
        can still meet it).
    relative
        Whether ``value`` is a fraction.
    text
        As the user wrote it.
    """

    value: float
    relative: bool
    text: str

    @classmethod
    def parse(cls, spec: BoundTolerance | str | float) -> BoundTolerance:
        """From ``0.5`` / ``"0.5"`` (absolute) or ``"5%"`` (relative).

        Raises
        ------
        InputError
            Not a positive finite number (percentages in (0, 100]).
        """
        if isinstance(spec, BoundTolerance):
            return spec
        text = str(spec).strip()
        relative = text.endswith("%")
        try:
            value = float(text[:-1] if relative else text)
        except ValueError:
            value = math.nan
        if relative:
            value /= 100.0
        if not (math.isfinite(value) and value > 0 and (not relative or value <= 1.0)):
            raise InputError(
                f"bound tolerance {text[:40]!r}: expected a positive width in the ranking's "
                "unit (mm² for one layer, mm³ for several), e.g. 0.5, or a percentage of "
                "the lost amount in (0, 100], e.g. 5%")
        return cls(value, relative, text)

    def allowed(self, t: Totals) -> float:
        """The width hi − lo allowed for a nozzle with these totals (its unit)."""
        if self.relative:
            return max(self.value * t.lost, self.value * 0.01 * t.target)
        return self.value


@dataclass(frozen=True)
class Refinement:
    """What the refinement of :func:`analyze` did and what it cost.

    Attributes
    ----------
    tolerance
        The bound tolerance asked for (text), or None.
    separate_ties
        Whether overlapping intervals were refined.
    rounds, tasks
        Refinement rounds run and layer × nozzle computations they made.
    work
        Their estimated work (units of :func:`raster_work`).
    elapsed
        Wall time of the refinement, s.
    met
        Every nozzle's width within its tolerance (None without a tolerance).
    stopped
        Why refinement ended: ``met``, ``separated``, ``nothing to refine``, ``budget``
        (tie separation's work budget), ``finest`` (no finer setting), ``limit`` (the
        memory or work guard), or ``rounds``.
    notes
        Human-readable remarks.
    """

    tolerance: str | None
    separate_ties: bool
    rounds: int
    tasks: int
    work: float
    elapsed: float
    met: bool | None
    stopped: str
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"tolerance": self.tolerance, "separate_ties": self.separate_ties,
                "rounds": self.rounds, "tasks": self.tasks, "work": self.work,
                "elapsed_s": self.elapsed, "met": self.met, "stopped": self.stopped,
                "notes": list(self.notes)}


def _weights(layers: Sequence[LayerOutcome], volume: bool) -> list[float]:
    return [o.height if volume else 1.0 for o in layers]


def _plan_steps(width: float, allowed: float) -> int:
    """Halvings of ``width`` needed to reach ``allowed`` (the raster's width ∝ h)."""
    if width <= allowed or allowed <= 0:
        return 0 if width <= allowed else 60
    return math.ceil(math.log2(width / allowed) - 1e-12)


def _refuse_plan(what: str, layer: Layer, noz: Nozzle, mach: Machine, engine: str,
                 settings: Settings, steps: int, max_work: float) -> None:
    """Refuse (ResourceError) when ``steps`` refinements of this layer would exceed a guard."""
    from printability.mmc.refine import refined_settings, refinement_work

    s = settings
    for _ in range(steps):
        nxt = refined_settings(engine, noz, mach, s)
        if nxt is None:
            break
        s = nxt
    if s is settings:
        return
    work, memory = refinement_work(layer.region, noz, mach, engine, s)
    step = f", angle step {s.angle_step:g}°" if s.angle_step is not None else ""
    if memory > settings.max_memory or work > max_work:
        minutes = work * _SECONDS_PER_WORK / 60
        raise ResourceError(
            f"{what}: nozzle {noz.spec} would need about {steps} refinement(s) of layer "
            f"{layer.index} (z={layer.z:g} mm), to --resolution {s.resolution:g} mm{step}: "
            f"about {memory / 2**20:,.0f} MiB (allowed {settings.max_memory / 2**20:,.0f} MiB) "
            f"and {work:.2g} operations, roughly {minutes:,.1f} minutes (allowed {max_work:.2g}); "
            "nothing was refined. Ask for a wider tolerance, or raise --max-memory")


def _precheck_tolerance(layers: LayerStack, nozs: Sequence[Nozzle], mach: Machine, engine: str,
                        settings: Settings, tol: BoundTolerance, max_work: float) -> None:
    """Refuse an absolute tolerance that the raster engine cannot meet within the guards.

    Before anything runs, the width is predicted from the boundary length: the plain
    raster engine's interval is about 2·h wide per mm of boundary (see
    :mod:`printability.mmc.raster`); each refinement halves h. Nozzles whose band the
    engine settles below the pixel (one circle or ellipse) are checked after the first
    pass instead, from the width it measured.
    """
    from printability.mmc.raster import _band_settles

    volume = uses_volume([lay.height for lay in layers])
    for noz in nozs:
        if _band_settles(noz):
            # its upper bound is settled below the pixel: the width is no longer 2·h per mm
            # of boundary, and is only known after the first pass (checked then)
            continue
        widths = []
        for layer in layers:
            eng = choose_engine(noz, mach, layer.region) if engine == "auto" else engine
            if eng != "raster":
                continue
            w = 2.0 * settings.resolution * float(layer.region.length)
            widths.append((w * (layer.height if volume else 1.0), w, layer, eng))
        if not widths:
            continue
        total = sum(w for w, *_ in widths)
        steps = _plan_steps(total, tol.value)
        if steps:
            _, _, layer, eng = max(widths, key=lambda t: t[0])
            _refuse_plan(f"--bound-tolerance {tol.text}", layer, noz, mach, eng, settings,
                         steps, max_work)


def _choose_layers(layers: Sequence[LayerOutcome], weights: Sequence[float], reduce_by: float,
                   ) -> list[int]:
    """Layers to refine so that their widths, halved, reduce the total by ``reduce_by``."""
    order = sorted(range(len(layers)), key=lambda k: -layers[k].width * weights[k])
    chosen, gain = [], 0.0
    for k in order:
        if layers[k].width * weights[k] <= 0:
            break
        chosen.append(k)
        gain += 0.5 * layers[k].width * weights[k]
        if gain >= reduce_by:
            break
    return chosen


def _merge(old: LayerOutcome, new: LayerOutcome) -> LayerOutcome:
    """A layer's refined outcome: the intersection of both certified intervals."""
    from printability.mmc.refine import merge_bounds

    lo, hi = merge_bounds(old.lost_area_bounds, new.lost_area_bounds,
                          target_area=old.target_area)
    lost = min(max(new.lost_area, lo), hi)
    return replace(new, lost_area=lost, as_built_area=old.target_area - lost,
                   lost_area_bounds=(lo, hi), elapsed=old.elapsed + new.elapsed,
                   refinements=old.refinements + 1)


def _refine(per_nozzle: list[NozzleAnalysis], layers: LayerStack, mach: Machine,
            settings: Settings, *, tol: BoundTolerance | None, separate: bool, budget: float,
            max_rounds: int, max_work: float, keep: bool, scheduler: str | None,
            on_progress: Callable[[int, int], None] | None,
            ) -> tuple[list[NozzleAnalysis], Refinement]:
    """Refine layers of some nozzles until the tolerance is met and/or ties separate.

    Each round picks, per nozzle that needs it, the layers whose widths weigh most
    (:func:`_choose_layers`), computes them again at the next finer settings
    (:func:`printability.mmc.refine.refined_settings`) and intersects the intervals.
    A tolerance whose predicted cost exceeds the memory or work guard is refused
    before its round runs (:func:`_refuse_plan`).
    """
    from printability.mmc.refine import refined_settings, refinement_work

    t0 = time.perf_counter()
    volume = uses_volume([lay.height for lay in layers])
    per = list(per_nozzle)
    cur = {(i, k): settings for i in range(len(per)) for k in range(len(layers))}
    first_work = sum(refinement_work(layers[k].region, per[i].nozzle, mach,
                                     per[i].layers[k].engine, settings)[0]
                     for i in range(len(per)) for k in range(len(layers)))
    spent, rounds, n_tasks = 0.0, 0, 0
    notes: list[str] = []
    stopped = "nothing to refine"
    blocked: set[tuple[int, int]] = set()
    while True:
        tots = [n.totals(volume=volume) for n in per]
        want: dict[int, float] = {}  # nozzle -> total width reduction wanted
        for i, t in enumerate(tots):
            if tol is not None:
                width = t.lost_bounds[1] - t.lost_bounds[0]
                allowed = tol.allowed(t)
                if width > allowed * (1 + 1e-12):
                    want[i] = max(want.get(i, 0.0), width - allowed)
        tol_needed = bool(want)
        pairs = []
        if separate:
            bounds = [t.lost_bounds for t in tots]
            for i, j in ties(bounds):
                wi = bounds[i][1] - bounds[i][0]
                wj = bounds[j][1] - bounds[j][0]
                floor = 1e-9 * max(tots[i].target, tots[j].target)
                if wi <= floor and wj <= floor:
                    continue  # equal to rounding: a true tie, broken by build time
                overlap = min(bounds[i][1], bounds[j][1]) - max(bounds[i][0], bounds[j][0])
                pairs.append((i, j))
                for k, w in ((i, wi), (j, wj)):
                    if w >= 0.25 * (wi + wj):
                        want[k] = max(want.get(k, 0.0), min(w, overlap + 1e-12))
        if not want:
            stopped = "met" if tol is not None else ("separated" if separate else stopped)
            break
        if rounds >= max_rounds:
            stopped = "rounds"
            break
        tasks, keys, round_work = [], [], 0.0
        reasons = set()
        for i, reduce_by in want.items():
            n = per[i]
            weights = _weights(n.layers, volume)
            for k in _choose_layers(n.layers, weights, reduce_by):
                if (i, k) in blocked:
                    continue
                o = n.layers[k]
                nxt = refined_settings(o.engine, n.nozzle, mach, cur[(i, k)])
                if nxt is None:
                    blocked.add((i, k))
                    reasons.add("finest")
                    continue
                if tol_needed and i in want and tol is not None:
                    t = tots[i]
                    steps = _plan_steps(t.lost_bounds[1] - t.lost_bounds[0], tol.allowed(t))
                    _refuse_plan(f"--bound-tolerance {tol.text}", layers[k], n.nozzle, mach,
                                 o.engine, cur[(i, k)], steps, max_work)
                work, memory = refinement_work(layers[k].region, n.nozzle, mach, o.engine, nxt)
                if memory > settings.max_memory or work > max_work:
                    blocked.add((i, k))
                    reasons.add("limit")
                    notes.append(f"{n.nozzle.spec}, layer {o.index}: not refined past "
                                 f"resolution {cur[(i, k)].resolution:g} mm (the next step "
                                 f"needs about {memory / 2**20:,.0f} MiB, {work:.2g} work)")
                    continue
                only_ties = not (tol is not None and tol_needed)
                if only_ties and spent + round_work + work > budget * first_work:
                    reasons.add("budget")
                    continue
                tasks.append((layers[k], n.nozzle, mach, o.engine, nxt, keep))
                keys.append((i, k, nxt))
                round_work += work
        if not tasks:
            stopped = ("limit" if "limit" in reasons else "budget" if "budget" in reasons
                       else "finest" if "finest" in reasons else "nothing to refine")
            break
        outs = list(_map(tasks, settings=settings, scheduler=scheduler, on_progress=on_progress))
        for (i, k, nxt), new in zip(keys, outs, strict=True):
            lay = list(per[i].layers)
            lay[k] = _merge(lay[k], new)
            per[i] = replace(per[i], layers=tuple(lay))
            cur[(i, k)] = nxt
        spent += round_work
        rounds += 1
        n_tasks += len(tasks)
    met = None
    if tol is not None:
        per = [replace(n, allowed_width=tol.allowed(n.totals(volume=volume))) for n in per]
        met = all(bool(n.tolerance_met) for n in per)
    return per, Refinement(
        tolerance=tol.text if tol is not None else None, separate_ties=separate, rounds=rounds,
        tasks=n_tasks, work=spent, elapsed=time.perf_counter() - t0, met=met, stopped=stopped,
        notes=tuple(dict.fromkeys(notes)))


def _process_context() -> multiprocessing.context.BaseContext:
    """Fork server where there is one: the caller may have threads (a progress bar's
    refresher, a Dask client) that a plain fork would copy mid-lock.

    The fork server is a new interpreter started with ``-c``, which puts the working
    directory first on ``sys.path``: a folder named ``printability`` there would be imported
    instead of this package (an editable install finds it last). It is started here with
    ``PYTHONSAFEPATH=1``, which leaves the working directory out; the workers it forks
    inherit its ``sys.path``. (Spawned children get the parent's ``sys.path`` back before
    they import anything of ours.)"""
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["printability.analysis", "printability.mmc.exact"])
        _start_forkserver_safe_path()
        return ctx
    return multiprocessing.get_context()


def _start_forkserver_safe_path() -> None:
    """Start the fork server (if it is not running) with ``PYTHONSAFEPATH=1`` in its
    environment, and the variable back as it was in ours."""
    from multiprocessing import forkserver

    saved = os.environ.get("PYTHONSAFEPATH")
    os.environ["PYTHONSAFEPATH"] = "1"
    try:
        forkserver.ensure_running()
    finally:
        if saved is None:
            del os.environ["PYTHONSAFEPATH"]
        else:
            os.environ["PYTHONSAFEPATH"] = saved


def _map(tasks: list[tuple], *, settings: Settings, scheduler: str | None,
         on_progress: Callable[[int, int], None] | None) -> Iterable[LayerOutcome]:
    total = len(tasks)
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError:
            raise InputError("--scheduler needs Dask: pip install 'printability[dask]'") from None
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise PrintabilityOSError(
                f"cannot reach the Dask scheduler at {scheduler} within {SCHEDULER_TIMEOUT} "
                f"({type(exc).__name__}: {' '.join(str(exc).split()) or 'no answer'}); start "
                "one with `dask scheduler` and workers with `dask worker ADDRESS`, or drop "
                "--scheduler to run on this machine") from None
        with client:
            futures = client.map(_run_task, tasks, pure=False)
            results = []
            for i, fut in enumerate(futures, 1):
                results.append(fut.result())
                if on_progress:
                    on_progress(i, total)
            return results
    if settings.workers > 1 and total > 1:
        with ProcessPoolExecutor(max_workers=min(settings.workers, total),
                                 mp_context=_process_context()) as pool:
            results = []
            for i, out in enumerate(pool.map(_run_task, tasks), 1):
                results.append(out)
                if on_progress:
                    on_progress(i, total)
            return results
    results = []
    for i, task in enumerate(tasks, 1):
        results.append(_run_task(task))
        if on_progress:
            on_progress(i, total)
    return results
