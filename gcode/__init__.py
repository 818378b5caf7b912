"""G-code as text: a fast, lossless reader (and, in ``gcode.writer``, a writer).

The reader keeps every byte of the file and adds numpy tables of lines,
words, moves and layers; see :mod:`gcode.reader`. It knows nothing of
geometry engines: turning moves into regions is
:mod:`printability.sources.gcode`'s job.
"""

from __future__ import annotations

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

__all__ = [
    "CATEGORIES",
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
