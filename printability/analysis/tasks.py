"""The layer × nozzle computations of an analysis, and where they run.

One task is one engine run (:func:`printability.mmc.compute_mmc`) of one nozzle on one
layer, made into a :class:`~printability.analysis.results.LayerOutcome`. Tasks are
independent: :class:`TaskRunner` runs them here, in ``settings.workers`` local
processes, or on a Dask cluster when ``scheduler`` names one (the ``dask`` extra).
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.context
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

from printability.errors import InputError, NozzleTooLargeError, PrintabilityOSError
from printability.mmc import choose_engine, compute_mmc
from printability.model.layers import Layer
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

from .results import LayerOutcome

__all__ = ["SCHEDULER_TIMEOUT", "TaskRunner", "layer_outcome", "run_task", "run_tasks"]

SCHEDULER_TIMEOUT = "20s"
"""How long to wait for a Dask scheduler to answer before giving up."""

Progress = Callable[[int, int], None]
"""Called with (done, total) after each task."""


def layer_outcome(layer: Layer, nozzle: Nozzle, machine: Machine, engine: str,
                  settings: Settings, keep: bool) -> LayerOutcome:
    """One nozzle on one layer: the engine's figures (and its result when ``keep``).

    A nozzle larger than the layer loses all of it (no engine result).
    """
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


def run_task(args: tuple) -> LayerOutcome:
    """:func:`layer_outcome` of one task tuple (what worker processes are handed)."""
    return layer_outcome(*args)


@dataclass(frozen=True)
class TaskRunner:
    """Where the tasks of one analysis run, and what their outcomes keep.

    Attributes
    ----------
    settings
        The analysis's settings: ``workers`` > 1 runs tasks in local processes, and a
        task made without its own settings uses these.
    keep
        Keep every engine result in the outcomes (geometry for the report).
    scheduler
        Address of a Dask scheduler to run the tasks on instead, or None.
    on_progress
        Called with (done, total) after each task of a batch.
    """

    settings: Settings
    keep: bool
    scheduler: str | None = None
    on_progress: Progress | None = None

    def task(self, layer: Layer, nozzle: Nozzle, machine: Machine, engine: str,
             settings: Settings | None = None) -> tuple:
        """The task tuple of one layer × nozzle (for :meth:`run`)."""
        return (layer, nozzle, machine, engine,
                self.settings if settings is None else settings, self.keep)

    def run(self, tasks: list[tuple]) -> list[LayerOutcome]:
        """The outcomes of a batch of tasks, in the order of the tasks."""
        return list(run_tasks(tasks, settings=self.settings, scheduler=self.scheduler,
                              on_progress=self.on_progress))


def run_tasks(tasks: list[tuple], *, settings: Settings, scheduler: str | None,
              on_progress: Progress | None) -> list[LayerOutcome]:
    """Run tasks on the Dask cluster at ``scheduler``, else in ``settings.workers``
    processes (when there are several tasks), else here; outcomes in task order."""
    if scheduler is not None:
        return _run_on_dask(tasks, scheduler, on_progress)
    if settings.workers > 1 and len(tasks) > 1:
        return _run_in_processes(tasks, settings.workers, on_progress)
    results = []
    for i, task in enumerate(tasks, 1):
        results.append(run_task(task))
        if on_progress:
            on_progress(i, len(tasks))
    return results


def _run_on_dask(tasks: list[tuple], scheduler: str,
                 on_progress: Progress | None) -> list[LayerOutcome]:
    total = len(tasks)
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
        futures = client.map(run_task, tasks, pure=False)
        results = []
        for i, fut in enumerate(futures, 1):
            results.append(fut.result())
            if on_progress:
                on_progress(i, total)
        return results


def _run_in_processes(tasks: list[tuple], workers: int,
                      on_progress: Progress | None) -> list[LayerOutcome]:
    total = len(tasks)
    with ProcessPoolExecutor(max_workers=min(workers, total),
                             mp_context=_process_context()) as pool:
        results = []
        for i, out in enumerate(pool.map(run_task, tasks), 1):
            results.append(out)
            if on_progress:
                on_progress(i, total)
        return results


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

