"""The analysis pipeline: :func:`analyze` and its stages.

1. :func:`_prepare` reads the nozzles, the machine and the refinement options;
2. :func:`_check_guards` refuses, before any engine runs, work beyond the guards;
3. :func:`_first_pass` runs every layer × nozzle (:mod:`.tasks`);
4. :func:`printability.analysis.refine.refine_nozzles` refines, when asked to;
5. :func:`_rank` orders the nozzles, with the ranks their certified bounds allow;
6. :func:`_assemble` makes the :class:`~printability.analysis.results.Analysis`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from printability.analysis.ranking import certified_ranks, ties, uses_volume
from printability.errors import InputError
from printability.model.layers import LayerStack
from printability.model.machine import Machine, parse_machine
from printability.model.nozzle import Nozzle, parse_nozzle
from printability.options import ENGINES
from printability.settings import DEFAULT_SETTINGS, Settings

from .refine import BoundTolerance, RefineOptions, precheck_tolerance, refine_nozzles
from .results import Analysis, NozzleAnalysis, Refinement
from .tasks import TaskRunner
from .work import RASTER_WORK_BUDGET, check_raster_work

__all__ = ["analyze"]


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
    refine: RefineOptions | None = None,
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
    refine
        What to refine after the first pass (:class:`RefineOptions`: a bound
        tolerance to meet, ties to separate, within a work budget and a number
        of rounds). None: no refinement.

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
        ``refine.bound_tolerance`` would need more memory or work than allowed
        (refused with the estimate before the refinement runs).
    """
    job = _prepare(layers, nozzles, machine, engine, refine or RefineOptions())
    _check_guards(job, settings, max_raster_work)
    t0 = time.perf_counter()
    runner = TaskRunner(settings, keep_results, scheduler, on_progress)
    per_nozzle = _first_pass(job, runner)
    refinement = None
    if job.refine.active:
        per_nozzle, refinement = refine_nozzles(
            per_nozzle, job.layers, job.machine, tol=job.tol, options=job.refine,
            max_work=max_raster_work, runner=runner)
    ranked = _rank(per_nozzle, job.machine, job.layers)
    return _assemble(job, settings, ranked, refinement, time.perf_counter() - t0)


@dataclass(frozen=True)
class _Job:
    """What :func:`analyze` was asked, read and checked."""

    layers: LayerStack
    nozzles: tuple[Nozzle, ...]
    machine: Machine
    engine: str
    refine: RefineOptions
    tol: BoundTolerance | None


def _prepare(layers: LayerStack, nozzles: Sequence[str | Nozzle], machine: str | Machine,
             engine: str, refine: RefineOptions) -> _Job:
    """Read the engine, nozzles, machine and refinement options (InputError when one is
    wrong)."""
    engine = ENGINES.check(engine)
    if not nozzles:
        raise InputError("analyze: give at least one nozzle (e.g. --nozzle circle:d=0.4)")
    nozs = tuple(parse_nozzle(n) for n in nozzles)
    mach = parse_machine(machine)
    return _Job(layers, nozs, mach, engine, refine, refine.tolerance())


def _check_guards(job: _Job, settings: Settings, max_raster_work: float) -> None:
    """Refuse (ResourceError), before any engine runs, a layer × nozzle beyond the raster
    engine's work budget, or an absolute tolerance the guards cannot afford."""
    check_raster_work(job.layers, job.nozzles, job.machine, job.engine, settings,
                      max_raster_work)
    if job.tol is not None and not job.tol.relative:
        precheck_tolerance(job.layers, job.nozzles, job.machine, job.engine, settings, job.tol,
                           max_raster_work)


def _first_pass(job: _Job, runner: TaskRunner) -> list[NozzleAnalysis]:
    """Every layer for every nozzle at the analysis's settings, grouped by nozzle."""
    tasks = [runner.task(layer, noz, job.machine, job.engine)
             for noz in job.nozzles for layer in job.layers]
    outcomes = runner.run(tasks)
    n_layers = len(job.layers)
    return [NozzleAnalysis(noz, tuple(outcomes[i * n_layers:(i + 1) * n_layers]))
            for i, noz in enumerate(job.nozzles)]


def _rank(per_nozzle: list[NozzleAnalysis], machine: Machine, layers: LayerStack,
          ) -> list[NozzleAnalysis]:
    """Order by the estimate in the ranking's unit; certified rank ranges and ties."""
    from printability.analysis.ranking import DEFAULT_SPEED, bead_width_for_time, rank_order

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


def _assemble(job: _Job, settings: Settings, ranked: list[NozzleAnalysis],
              refinement: Refinement | None, elapsed: float) -> Analysis:
    """The analysis: one engine name when every layer used the same, else ``mixed``."""
    used = {o.engine for n in ranked for o in n.layers}
    return Analysis(
        input=job.layers.source,
        machine=job.machine,
        engine=used.pop() if len(used) == 1 else "mixed",
        settings=settings,
        layers=job.layers,
        nozzles=tuple(ranked),
        elapsed=elapsed,
        refinement=refinement,
    )
