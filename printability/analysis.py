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
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = ["RASTER_WORK_BUDGET", "Analysis", "LayerOutcome", "NozzleAnalysis", "analyze",
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
            **({"note": self.note} if self.note else {}),
        }


@dataclass(frozen=True)
class NozzleAnalysis:
    """One nozzle over all layers; areas in mm², volumes in mm³ (Σ area·height)."""

    nozzle: Nozzle
    layers: tuple[LayerOutcome, ...]
    rank: int = 0
    build_time: float = 0.0

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
            out.update(
                target_volume=self.volume("target_area"),
                as_built_volume=self.volume("as_built_area"),
                lost_volume=self.volume("lost_area"),
            )
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

    @property
    def multi_layer(self) -> bool:
        return len(self.layers) > 1

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
            "nozzles": [n.to_json(multi_layer=self.multi_layer) for n in self.nozzles],
        }


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
                        r.components.count, r.engine, r.elapsed, r if keep else None)


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
        :func:`raster_work`); checked for every task before any runs.

    Returns
    -------
    Analysis
        Nozzles ranked by lost area (volume for several layers), ties broken by
        the build-time estimate.

    Raises
    ------
    ResourceError
        A layer × nozzle would take the raster engine more than ``max_raster_work``
        (the message gives the estimate and a resolution that fits).
    """
    engine = ENGINES.check(engine)
    if not nozzles:
        raise InputError("analyze: give at least one nozzle (e.g. --nozzle circle:d=0.4)")
    nozs = [parse_nozzle(n) for n in nozzles]
    mach = parse_machine(machine)
    _check_raster_work(layers, nozs, mach, engine, settings, max_raster_work)
    t0 = time.perf_counter()
    tasks = [(layer, noz, mach, engine, settings, keep_results) for noz in nozs for layer in layers]
    outcomes = list(_map(tasks, settings=settings, scheduler=scheduler, on_progress=on_progress))
    per_nozzle = []
    n_layers = len(layers)
    for i, noz in enumerate(nozs):
        per_nozzle.append(NozzleAnalysis(noz, tuple(outcomes[i * n_layers:(i + 1) * n_layers])))
    ranked = _rank(per_nozzle, mach)
    used = {o.engine for o in outcomes}
    return Analysis(
        input=layers.source,
        machine=mach,
        engine=used.pop() if len(used) == 1 else "mixed",
        settings=settings,
        layers=layers,
        nozzles=tuple(ranked),
        elapsed=time.perf_counter() - t0,
    )


def _rank(per_nozzle: list[NozzleAnalysis], machine: Machine) -> list[NozzleAnalysis]:
    from printability.ranking import DEFAULT_SPEED, bead_width_for_time, rank_order

    timed = []
    for n in per_nozzle:
        w = bead_width_for_time(n.nozzle, rotary=machine.has_rotary and not n.nozzle.is_round)
        timed.append(replace(n, build_time=n.as_built_area / (w * DEFAULT_SPEED)))
    multi = any(o.height > 0 for n in timed for o in n.layers)
    lost = [n.volume("lost_area") if multi else n.lost_area for n in timed]
    ordered = [timed[i] for i in rank_order(lost, [n.build_time for n in timed])]
    return [replace(n, rank=i + 1) for i, n in enumerate(ordered)]


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
