"""Array helpers the hot paths share.

:func:`take_rows` is ``a[idx]`` for an integer index array, by ``np.take``: numpy 2 gathers
the rows of a 2-d array by fancy indexing about ten times slower (0.57 against 0.04 ms for
40 000 rows) and structured records about 25 times slower (1.2 against 0.05 ms for the
calibration cube's 8 700 moves); the values are the same.
"""

from __future__ import annotations

import numpy as np

__all__ = ["take_rows"]


def take_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` for an integer index array ``idx`` (not a boolean mask): the rows (or
    records) of ``a`` along its first axis, as a new array."""
    return np.take(a, idx, axis=0)
