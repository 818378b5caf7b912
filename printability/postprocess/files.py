"""Post-processing a file: read it (after the memory guard), run :func:`postprocess_bytes`,
and replace it atomically."""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from pathlib import Path

from printability.base.files import replace_file
from printability.errors import PrintabilityOSError
from printability.model.nozzle import parse_nozzle
from printability.postprocess.memory import check_memory
from printability.postprocess.options import DEFAULT_OPTIONS, PostprocessOptions
from printability.postprocess.pipeline import postprocess_bytes
from printability.postprocess.progress import PROGRESS, ProgressCallback, progress
from printability.postprocess.results import PostprocessResult


def write_atomic(path: Path, content: bytes) -> None:
    """Write ``content`` to ``path`` through :func:`printability.base.files.replace_file`:
    the file keeps the mode and, where this process may set it, the owner of the one it
    replaces; a new file gets 0666 less the umask; a kill while writing leaves no
    temporary file beside it."""
    replace_file(path, content)


def postprocess_file(
    path: str | os.PathLike[str],
    *,
    options: PostprocessOptions = DEFAULT_OPTIONS,
    output: str | os.PathLike[str] | None = None,
    env: Mapping[str, str] | None = None,
    on_progress: ProgressCallback | None = None,
) -> PostprocessResult:
    """Post-process a G-code file, in place unless ``output`` is given.

    The file is replaced atomically (temporary file + ``os.replace``), so on
    any error the slicer's file is left exactly as it was. When
    ``options.output_name`` is set, the new final name is written to
    ``<path>.output_name`` (one line), the file PrusaSlicer ≥ 2.4 reads after
    the script ends to rename its output.

    Parameters
    ----------
    path
        The G-code file (for a slicer: the last command-line argument).
    options
        See :class:`PostprocessOptions`.
    output
        Write here instead of in place.
    env
        Environment with the slicer's ``SLIC3R_*`` settings (default: ``os.environ``).
    on_progress
        Called as ``on_progress(stage, done, total)`` when a stage starts ("reading the
        G-code", "planning the layers", "rewriting the moves", "estimating the print time",
        "writing FILE") and as the layers are planned (``total`` 0: a stage with no count).

    Raises
    ------
    PrintabilityOSError, FileFormatError, InputError
    """
    token = PROGRESS.set(on_progress)
    try:
        return _postprocess_file(Path(path), options=options, output=output, env=env)
    finally:
        PROGRESS.reset(token)


def _postprocess_file(p: Path, *, options: PostprocessOptions,
                      output: str | os.PathLike[str] | None,
                      env: Mapping[str, str] | None) -> PostprocessResult:
    data = _read_gcode_file(p, options)
    environ = dict(os.environ) if env is None else dict(env)
    new, res = postprocess_bytes(data, path=str(p), options=options, env=environ)
    target = Path(output) if output is not None else p
    if res.already_processed and output is None:
        return res
    progress(f"writing {target.name}")
    try:
        write_atomic(target, new)
    except OSError as exc:
        raise PrintabilityOSError(f"{target}: cannot write the post-processed G-code "
                                  f"({exc.strerror or exc}); the original is unchanged") from None
    if options.output_name:
        try:
            write_atomic(Path(str(p) + ".output_name"),
                         options.output_name.encode("utf-8") + b"\n")
        except OSError as exc:
            raise PrintabilityOSError(f"{p}.output_name: cannot write the output name "
                                      f"({exc.strerror or exc})") from None
    return PostprocessResult(**{**res.__dict__, "output": str(target)})


def _read_gcode_file(p: Path, options: PostprocessOptions) -> bytes:
    """The bytes of a regular file, once the memory guard lets them in."""
    try:
        st = p.stat()
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read the G-code file "
                                  f"({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        # a device or a FIFO: /dev/zero would be read until memory runs out, a FIFO waited on
        raise PrintabilityOSError(f"{p}: not a regular file (expected a G-code file a slicer "
                                  "wrote)")
    # a nozzle that is not round plans every move: that estimate, before anything is read
    check_memory(st.st_size, p, planned=options.nozzle is not None
                 and not parse_nozzle(options.nozzle).is_round)
    try:
        return p.read_bytes()
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read the G-code file "
                                  f"({exc.strerror or exc})") from None
