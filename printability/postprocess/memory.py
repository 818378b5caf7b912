"""The memory guard: a run that would need more memory than allowed is refused before it
grows."""

from __future__ import annotations

from printability.errors import ResourceError
from printability.settings import DEFAULT_SETTINGS

#: Peak memory of a run per byte of G-code, measured (peak RSS less the libraries' 0.2 GB):
#: the slicer's moves kept as they are (a round nozzle no larger than the slicer's), 22.6 for
#: a 200 MB, 8.5 M-line file; every move planned and turned (an elliptical nozzle), 90 on
#: 2-15 MB files: the plan, and the output (2.5 times as many lines) read again for its print
#: time.
BYTES_PER_BYTE_KEPT = 25
BYTES_PER_BYTE_PLANNED = 100


def check_memory(size: int, path: object, *, binary: bool = False,
                 planned: bool = False) -> None:
    """Refuse ``size`` bytes of G-code text that would need more memory than allowed: checked
    before the file is read (``planned`` False: the least any run needs), and again once the
    file says its moves must be planned (``planned``)."""
    factor = BYTES_PER_BYTE_PLANNED if planned else BYTES_PER_BYTE_KEPT
    need = factor * size
    if need > DEFAULT_SETTINGS.max_memory:
        what = "G-code (decoded from the binary file)" if binary else "G-code"
        how = (" with this nozzle (every move planned)" if planned else "")
        raise ResourceError(f"{path}: {size / 2**20:.0f} MiB of {what} would need about "
                            f"{need / 2**30:.1f} GiB of memory to post-process{how}, more "
                            f"than the limit of {DEFAULT_SETTINGS.max_memory / 2**30:.1f} GiB "
                            "(half this machine's memory); split the print or use a larger "
                            "machine")
