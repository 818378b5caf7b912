"""The binary G-code path: binary G-code in, binary G-code out, its G-code post-processed as
text."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import replace

from gcode.bgcode import (
    GCODE_ENCODINGS,
    PRINT_METADATA,
    PRINTER_METADATA,
    decode_bgcode,
    encode_bgcode,
    rescaled_metadata,
)
from printability import __version__
from printability.postprocess.memory import check_memory
from printability.postprocess.options import PostprocessOptions
from printability.postprocess.results import PostprocessResult, unchanged_result
from printability.postprocess.scan import PROCESSED_KEY, binary_processed

#: ``postprocess_bytes`` (the text it is given: the G-code and the metadata comments)
TextPass = Callable[..., tuple[bytes, PostprocessResult]]


def postprocess_binary(
    data: bytes,
    postprocess_text: TextPass,
    *,
    path: str,
    options: PostprocessOptions,
    env: Mapping[str, str] | None,
) -> tuple[bytes, PostprocessResult]:
    """Post-process binary G-code: binary G-code in, binary G-code out.

    The file is decoded (:func:`gcode.bgcode.decode_bgcode`: every block's CRC checked) to
    its text form, the G-code followed by the metadata as the comments a text file ends with
    (the slicer, its flavor and nozzle are read there as from a text file); that text goes
    through ``postprocess_text`` (:func:`~printability.postprocess.postprocess_bytes`,
    called as ``postprocess_text(text, path=, options=, env=)``), and its G-code part is
    encoded back (:func:`gcode.bgcode.encode_bgcode`): the G-code blocks it leaves as they
    were and every thumbnail and metadata block are kept byte for byte, the rest re-encoded
    with the file's own compression and encoding. The metadata PrusaSlicer derives from the
    G-code are updated in the print and printer metadata
    (:func:`gcode.bgcode.rescaled_metadata`): the estimated printing times by the ratio of
    the print times the firmware's planner gives the new and the old G-code, the filament
    used and its cost by the ratio of the filament the extruding moves push. Line numbers in
    messages are those of the G-code.
    """
    t_start = time.perf_counter()
    doc = decode_bgcode(data, path=path)
    check_memory(len(doc.gcode), path, binary=True)
    n_in = doc.gcode.count(b"\n")
    if binary_processed(doc):
        return data, unchanged_result(path, n_in, binary=doc.describe())
    trailer = doc.trailer()
    new_text, res = postprocess_text(doc.gcode + trailer, path=path, options=options, env=env)
    if not new_text.endswith(trailer):  # pragma: no cover - the metadata comments are kept
        raise RuntimeError(f"{path}: post-processing changed the metadata comments after the "
                           "G-code")
    gcode = new_text[:len(new_text) - len(trailer)]
    time_factor = res.print_time_out / res.print_time_in \
        if res.print_time_in and res.print_time_out is not None else None
    filament_factor = res.filament_out / res.filament_in \
        if res.filament_in and res.filament_out is not None else None
    updates: dict[int, dict[str, str]] = {}
    for kind in (PRINT_METADATA, PRINTER_METADATA):
        updates[kind] = rescaled_metadata(doc.metadata_of(kind), time_factor=time_factor,
                                          filament_factor=filament_factor)
    notes = list(res.notes)
    if GCODE_ENCODINGS[doc.encoding] == "MeatPack":
        # this encoding keeps no comment: the marker goes in the print metadata
        updates[PRINT_METADATA][PROCESSED_KEY] = f"printability {__version__}"
        notes.append("binary G-code encoded with MeatPack without comments: the comment "
                     "block is not kept, the print metadata say the file was post-processed")
    changed = sorted({k for u in updates.values() for k in u} - {PROCESSED_KEY})
    if changed:
        notes.append("binary G-code metadata updated: " + ", ".join(changed))
    new = encode_bgcode(doc, gcode, metadata=updates)
    n_trailer = trailer.count(b"\n")
    return new, replace(res, lines_in=res.lines_in - n_trailer,
                        lines_out=res.lines_out - n_trailer, notes=tuple(notes),
                        binary=doc.describe(), elapsed=time.perf_counter() - t_start)
