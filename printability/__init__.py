"""printability: Maximum Material Condition analysis of layers for any nozzle on any machine.

The library's entry points:

- :func:`printability.mmc.compute_mmc` — P, S and the lost area of one layer;
- :func:`printability.nozzle.parse_nozzle`, :func:`printability.machine.parse_machine`;
- :class:`printability.settings.Settings` — tolerances travel in this frozen object.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]

# before any kernel is loaded: on-disk kernel caches older than a kernel module they
# compiled in are removed (numba checks only each kernel's own file; see _jit_cache)
from printability._jit_cache import check as _check_kernel_caches

_check_kernel_caches()
