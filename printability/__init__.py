"""printability: Maximum Material Condition analysis of layers for any nozzle on any machine.

The library's entry points:

- :func:`printability.mmc.compute_mmc` — P, S and the lost area of one layer;
- :func:`printability.model.nozzle.parse_nozzle`, :func:`printability.model.machine.parse_machine`;
- :class:`printability.settings.Settings` — tolerances travel in this frozen object.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]

# Importing the package runs nothing: the kernel-cache check (printability.base.kernel_cache)
# runs before the first kernel compiles or loads, armed by each kernel module's guard().
