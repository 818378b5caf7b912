"""Sharing one compiled kernel's independent items out over threads.

The kernels release the GIL (``numba.njit(nogil=True)``), so threads run them side by
side. Each item's answer is its own whichever thread computes it: the result is the same
on any number of threads.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable

import numpy as np

__all__ = ["shared_out"]


def shared_out(run: Callable[[slice], None], weight: np.ndarray, workers: int, *,
               min_items: int) -> None:
    """``run(part)`` over consecutive slices that cover the items ``0 … len(weight) - 1``,
    one per thread, cut where the cumulative ``weight`` (the work per item, any unit) is
    shared evenly.

    A part gets at least ``min_items`` items (a thread's start costs about 50 µs): fewer
    items in all, or ``workers`` ≤ 1, run on the calling thread. The caller's thread runs
    the first part; an exception on any thread is raised on the caller's once every part
    is done.
    """
    n = len(weight)
    parts = min(int(workers), n // max(1, int(min_items)))
    if parts <= 1:
        run(slice(0, n))
        return
    cum = np.cumsum(weight, dtype=float)
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts, side="right")
    edges = [0, *np.unique(np.clip(cuts, 1, n - 1)).tolist(), n]
    errors: list[BaseException] = []

    def guarded(part: slice) -> None:
        try:
            run(part)
        except BaseException as exc:  # raised on the caller's thread below
            errors.append(exc)

    threads = [threading.Thread(target=guarded, args=(slice(lo, hi),), daemon=True)
               for lo, hi in itertools.pairwise(edges[1:])]
    for t in threads:
        t.start()
    guarded(slice(edges[0], edges[1]))
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
