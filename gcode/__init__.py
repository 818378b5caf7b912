"""G-code as text: a fast, lossless reader (and, in ``gcode.writer``, a writer).

The reader keeps every byte of the file and adds numpy tables of lines,
words, moves and layers; see :mod:`gcode.reader`. It knows nothing of
geometry engines: turning moves into regions is
:mod:`printability.sources.gcode`'s job.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# The public names load their modules on first use (PEP 562): the reader compiles with numba,
# and gcode.flavors (which machine profiles import) must not pay for it.
_WHERE = {
    "KIND_BLANK": "gcode._lexer", "KIND_COMMAND": "gcode._lexer", "KIND_COMMENT": "gcode._lexer",
    "KIND_EXTENDED": "gcode._lexer", "KIND_OTHER": "gcode._lexer", "KIND_WORDS": "gcode._lexer",
    "MF_E_RELATIVE": "gcode._machine", "MF_INCH": "gcode._machine",
    "MF_RETRACTED": "gcode._machine", "MF_XYZ_RELATIVE": "gcode._machine",
    "SEGMENT_DTYPE": "gcode.arcs", "arc_chord_count": "gcode.arcs", "arc_length": "gcode.arcs",
    "linearise": "gcode.arcs",
    "CATEGORIES": "gcode.dialects", "NON_PART_CATEGORIES": "gcode.dialects",
    "feature_category": "gcode.dialects",
    "ParsedLine": "gcode.line", "Segment": "gcode.line", "Word": "gcode.line",
    "extended_params": "gcode.line", "parse_line": "gcode.line",
    "LAYER_DTYPE": "gcode.reader", "LINE_DTYPE": "gcode.reader", "MOVE_DTYPE": "gcode.reader",
    "WORD_DTYPE": "gcode.reader", "GCodeFile": "gcode.reader", "parse_gcode": "gcode.reader",
    "read_gcode": "gcode.reader",
}

if TYPE_CHECKING:  # pragma: no cover
    from gcode._lexer import (
        KIND_BLANK,
        KIND_COMMAND,
        KIND_COMMENT,
        KIND_EXTENDED,
        KIND_OTHER,
        KIND_WORDS,
    )
    from gcode._machine import MF_E_RELATIVE, MF_INCH, MF_RETRACTED, MF_XYZ_RELATIVE
    from gcode.arcs import SEGMENT_DTYPE, arc_chord_count, arc_length, linearise
    from gcode.dialects import CATEGORIES, NON_PART_CATEGORIES, feature_category
    from gcode.line import ParsedLine, Segment, Word, extended_params, parse_line
    from gcode.reader import (
        LAYER_DTYPE,
        LINE_DTYPE,
        MOVE_DTYPE,
        WORD_DTYPE,
        GCodeFile,
        parse_gcode,
        read_gcode,
    )


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'gcode' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


__all__ = [
    "CATEGORIES",
    "KIND_BLANK",
    "KIND_COMMAND",
    "KIND_COMMENT",
    "KIND_EXTENDED",
    "KIND_OTHER",
    "KIND_WORDS",
    "LAYER_DTYPE",
    "LINE_DTYPE",
    "MF_E_RELATIVE",
    "MF_INCH",
    "MF_RETRACTED",
    "MF_XYZ_RELATIVE",
    "MOVE_DTYPE",
    "NON_PART_CATEGORIES",
    "SEGMENT_DTYPE",
    "WORD_DTYPE",
    "GCodeFile",
    "ParsedLine",
    "Segment",
    "Word",
    "arc_chord_count",
    "arc_length",
    "extended_params",
    "feature_category",
    "linearise",
    "parse_gcode",
    "parse_line",
    "read_gcode",
]
