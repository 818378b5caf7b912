"""How far the run under way is: the ``on_progress`` callback :func:`postprocess_file` was
given, reached from every stage through a context variable."""

from __future__ import annotations

import contextvars
from collections.abc import Callable, Iterator

#: ``on_progress(stage, done, total)`` of the run under way (:func:`postprocess_file`'s
#: ``on_progress``); ``total`` 0 when the stage has no count
ProgressCallback = Callable[[str, int, int], None]
PROGRESS: contextvars.ContextVar[ProgressCallback | None] = contextvars.ContextVar(
    "printability_postprocess_progress", default=None)


def progress(stage: str, done: int = 0, total: int = 0) -> None:
    """Tell the run's ``on_progress`` (if any) which stage it is in and how far."""
    report = PROGRESS.get()
    if report is not None:
        report(stage, done, total)


def counted(batches: Iterator[tuple], total: int) -> Iterator[tuple]:
    """``batches`` of :func:`printability.planning.targets.layer_targets`, each reported as planned
    when the next one is asked for (a batch's first item is its layers)."""
    done = 0
    progress("planning the layers", 0, total)
    for batch in batches:
        yield batch
        done += len(batch[0])
        progress("planning the layers", done, total)
