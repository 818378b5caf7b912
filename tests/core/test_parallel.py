"""printability.base.parallel.shared_out: every item once, in parts of even work, errors kept."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from printability.base.parallel import shared_out


def _record(weight, workers, min_items):
    seen = []
    lock = threading.Lock()

    def run(part: slice) -> None:
        with lock:
            seen.append((part.start, part.stop, threading.get_ident()))

    shared_out(run, np.asarray(weight, float), workers, min_items=min_items)
    return sorted(seen)


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
@pytest.mark.parametrize("n", [0, 1, 5, 40, 1001])
def test_parts_cover_every_item_once(n, workers):
    rng = np.random.default_rng(n + workers)
    parts = _record(rng.integers(0, 5, n), workers, 4)
    stops = [0] + [p[1] for p in parts]
    assert [p[0] for p in parts] == stops[:-1]  # consecutive, no gap, no overlap
    assert stops[-1] == n
    assert len(parts) <= max(1, min(workers, n // 4))
    assert all(p[1] > p[0] for p in parts) or n == 0


def test_parts_share_the_work_and_run_on_threads():
    weight = np.r_[np.full(100, 9.0), np.ones(900)]  # the first tenth holds half the work
    parts = _record(weight, 2, 10)
    assert [(a, b) for a, b, _ in parts] == [(0, 100), (100, 1000)]
    assert len({t for _, _, t in parts}) == 2
    assert _record(np.ones(19), 2, 10) == [(0, 19, threading.get_ident())]  # too few items


def test_an_error_on_a_thread_reaches_the_caller_after_every_part():
    done = []

    def run(part: slice) -> None:
        if part.start > 0:
            raise ValueError("bad part")
        done.append(part)

    with pytest.raises(ValueError, match="bad part"):
        shared_out(run, np.ones(100), 2, min_items=10)
    assert done == [slice(0, 50)]
