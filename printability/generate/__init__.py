"""Generate a complete G-code file for a T-T-R machine from layers (``printability generate``).

The stages are in :mod:`.pipeline`; the compiled kernels of the emitter in
:mod:`._emit_kernel` and of the grouping in :mod:`._group_kernel`.
"""

from printability.generate.pipeline import (
    GenerateOptions,
    GenerateResult,
    generate_file,
    generate_gcode,
)

__all__ = ["GenerateOptions", "GenerateResult", "generate_file", "generate_gcode"]
