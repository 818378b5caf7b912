"""Read a G-code file: raw lines kept byte for byte, tables for everything else.

>>> from gcode import read_gcode
>>> g = read_gcode("part.gcode")                     # doctest: +SKIP
>>> g.line(10)                                       # the 11th line, exact bytes  # doctest: +SKIP
>>> m = g.moves[g.moves["is_extrusion"]]             # numpy structured array  # doctest: +SKIP
>>> g.layers["z"], g.layers["height"]                # doctest: +SKIP

Design (for readers and for the writer that rewrites some moves):

* :class:`GCodeFile` holds the file's ``data`` (bytes) and the start offset of
  every line; line *i* is ``data[start[i]:start[i+1]]`` with its own
  terminator, so ``g.to_bytes() == data`` and any line not rewritten can be
  copied out untouched. :meth:`GCodeFile.parsed` gives a lossless token
  stream of one line (:class:`gcode.line.ParsedLine`).
* ``g.lines`` (:data:`LINE_DTYPE`), ``g.words`` (:data:`WORD_DTYPE`),
  ``g.moves`` (:data:`MOVE_DTYPE`) and ``g.layers`` (:data:`LAYER_DTYPE`) are
  numpy structured arrays: one row per line / word / G0-G3 move / layer, no
  per-line Python objects.
* Layers come from the slicer's markers (see :mod:`gcode.dialects`) or, in
  files without any, from the Z of extrusion moves: a layer starts at the
  first Z change after the previous layer's last extrusion, and in spiral
  (vase) files whenever the extruding nozzle has risen by a nominal layer
  height since the layer started.

Binary G-code (``.bgcode``) is read as its text form (:mod:`gcode.bgcode`).

Errors name the file and the 1-based line: binary data is refused, a stray
non-UTF-8 byte in a comment is kept as it is, a move whose words are not
numbers is refused, and a file cut off in the middle of a line says so.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcode._lexer import (
    KIND_BLANK,
    KIND_COMMAND,
    KIND_EXTENDED,
    KIND_OTHER,
    LINE_FIELDS,
    WORD_FIELDS,
    WORD_MALFORMED,
    WORD_VALUELESS,
    lex,
)
from gcode._machine import ERR_MESSAGES, run_machine
from gcode.arcs import linearise
from gcode.dialects import CommentInfo, feature_category, scan_comments
from gcode.line import ParsedLine, parse_line
from printability.base.errors import (
    EXCERPT_LENGTH,
    FileFormatError,
    InputError,
    PrintabilityOSError,
    ResourceError,
    excerpt,
)
from printability.base.options import FLAVORS
from printability.base.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "LAYER_DTYPE",
    "LINE_DTYPE",
    "MOVE_DTYPE",
    "WORD_DTYPE",
    "GCodeFile",
    "parse_gcode",
    "read_gcode",
]

LINE_DTYPE = np.dtype(
    [("start", "i8"), ("content_end", "i8"), ("comment_start", "i8"), ("kind", "u1"),
     ("letter", "u1"), ("major", "i4"), ("minor", "i4"), ("command_end", "i8"),
     ("line_number", "i8"), ("checksum", "i4"), ("checksum_ok", "?"), ("word_first", "i8"),
     ("word_count", "i4"), ("bad_column", "i4"), ("control_column", "i4"), ("layer", "i4")]
)
"""One row per line. Offsets are absolute in ``data``; ``-1`` means none. ``kind`` is one of
:data:`gcode.KIND_BLANK`, ``KIND_COMMENT``, ``KIND_COMMAND``, ``KIND_EXTENDED``,
``KIND_WORDS``, ``KIND_OTHER``."""

WORD_DTYPE = np.dtype(
    [("line", "i4"), ("letter", "u1"), ("value", "f8"), ("start", "i8"), ("end", "i8"),
     ("flags", "u1")]
)
"""One row per address word; ``value`` is NaN for valueless/quoted words."""

MOVE_DTYPE = np.dtype(
    [("line", "i8"), ("kind", "u1"), ("x0", "f8"), ("y0", "f8"), ("z0", "f8"), ("x1", "f8"),
     ("y1", "f8"), ("z1", "f8"), ("e", "f8"), ("feed", "f8"), ("tool", "i2"), ("cx", "f8"),
     ("cy", "f8"), ("sweep", "f8"), ("r0", "f8"), ("r1", "f8"), ("flags", "u1"),
     ("e_pos", "f8"), ("is_extrusion", "?"), ("wipe", "?"), ("feature", "i2"), ("width", "f8"),
     ("layer", "i4")]
)
"""One row per G0/G1/G2/G3 line.

``kind`` 0-3 (G0..G3); start/end machine coordinates in mm (NaN: not known
yet); ``e`` filament fed, mm; ``e_pos`` the logical E after the move
(G92 frame; what an absolute-E file writes), mm; ``feed`` mm/min; ``cx, cy, sweep, r0, r1``
the arc's centre, signed sweep (rad, CCW > 0) and radii; ``flags`` bits
1 E relative, 2 XYZ relative, 4 inches, 8 firmware-retracted;
``is_extrusion``: E > 0 and the nozzle moves in XY; ``wipe``: inside a
``WIPE_START``/``WIPE_END`` block; ``feature`` index into
``GCodeFile.features`` (-1 before the first feature comment); ``width`` the
slicer's line width in mm (NaN when the file gives none); ``layer`` index
into ``GCodeFile.layers`` (-1 before the first layer)."""

LAYER_DTYPE = np.dtype(
    [("line", "i8"), ("z", "f8"), ("height", "f8"), ("first_move", "i8"), ("end_move", "i8"),
     ("n_extrusions", "i8")]
)
"""One row per layer: its first line, its Z (top of the layer, mm) and
height (mm), and the moves ``[first_move, end_move)`` that belong to it."""

_BGCODE_MAGIC = b"GCDE"


@dataclass(frozen=True, eq=False)
class GCodeFile:
    """A parsed G-code file. Build it with :func:`read_gcode` or :func:`parse_gcode`."""

    path: str
    data: bytes
    lines: np.ndarray
    words: np.ndarray
    moves: np.ndarray
    layers: np.ndarray
    features: tuple[str, ...]
    feature_categories: tuple[str, ...]
    dialect: str
    slicer: str
    flavor: str
    arcwelder: bool
    warnings: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.lines)

    def line(self, i: int) -> bytes:
        """Line ``i`` (0-based) exactly as in the file, terminator included."""
        s = self.lines["start"]
        end = s[i + 1] if i + 1 < len(s) else len(self.data)
        return self.data[s[i] : end]

    def iter_lines(self):
        """All lines, exact bytes (``b"".join(g.iter_lines()) == g.data``)."""
        s = [*self.lines["start"].tolist(), len(self.data)]
        d = self.data
        return (d[a:b] for a, b in itertools.pairwise(s))

    def to_bytes(self) -> bytes:
        """The file, byte for byte."""
        return b"".join(self.iter_lines())

    def parsed(self, i: int) -> ParsedLine:
        """Lossless token stream of line ``i``."""
        return parse_line(self.line(i))

    def line_words(self, i: int) -> np.ndarray:
        """Rows of :attr:`words` on line ``i``."""
        f = self.lines["word_first"][i]
        return self.words[f : f + self.lines["word_count"][i]]

    def feature_category_of_moves(self) -> np.ndarray:
        """Category name of each move's feature (object array, same length as moves)."""
        cats = np.array([*self.feature_categories, self._before_first_feature()], dtype=object)
        return cats[self.moves["feature"]]

    def moves_in(self, categories) -> np.ndarray:
        """Per move, True where its feature's category is one of ``categories``: one test
        per feature, then a gather (a few features, up to millions of moves)."""
        names = [*self.feature_categories, self._before_first_feature()]
        table = np.array([c in categories for c in names], dtype=bool)
        return table[self.moves["feature"]]

    def _before_first_feature(self) -> str:
        # Moves before any feature comment are start G-code (purge lines...)
        # in files that have feature comments at all.
        return "custom" if self.features else "unknown"

    def segments(self, *, settings: Settings = DEFAULT_SETTINGS, moves: np.ndarray | None = None):
        """Moves as straight chords (arcs linearised within ``settings.chord_tolerance``).

        Returns a :data:`gcode.arcs.SEGMENT_DTYPE` array whose ``move`` field
        indexes ``moves`` (default: all of :attr:`moves`).
        """
        return linearise(self.moves if moves is None else moves, settings.chord_tolerance)


def read_gcode(
    path: str | os.PathLike[str],
    *,
    flavor: str = "auto",
    engine: str = "numba",
    settings: Settings = DEFAULT_SETTINGS,
) -> GCodeFile:
    """Read and parse a G-code file (see :func:`parse_gcode`)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read G-code file: {exc.strerror or exc}") from exc
    _check_memory(size, p, settings)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read G-code file: {exc.strerror or exc}") from exc
    return parse_gcode(data, path=str(p), flavor=flavor, engine=engine, settings=settings)


def _check_memory(size: int, path: object, settings: Settings) -> None:
    # tables: ~40 B per byte of input at worst (a word every 3 bytes), usually ~8
    need = 40 * size
    if need > settings.max_memory:
        raise ResourceError(
            f"{path}: a {size / 1e6:.0f} MB G-code file needs up to {need / 1e9:.1f} GB to "
            f"parse, more than the {settings.max_memory / 1e9:.1f} GB allowed (Settings.max_memory)"
        )


def parse_gcode(
    data: bytes,
    *,
    path: str = "<bytes>",
    flavor: str = "auto",
    engine: str = "numba",
    settings: Settings = DEFAULT_SETTINGS,
) -> GCodeFile:
    """Parse G-code bytes.

    Parameters
    ----------
    data
        The file's content. Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7; recognised by
        its ``GCDE`` start) is decoded first (:mod:`gcode.bgcode`): the result's ``data``
        is then its text form, the G-code followed by its metadata as comments.
    path
        Name used in messages.
    flavor
        Firmware semantics of G90/G91 for E: ``"auto"`` (from the slicer's
        ``;FLAVOR:``/``gcode_flavor`` comment, Marlin if none) or one of
        :data:`printability.options.FLAVORS`.
    engine
        ``"numba"`` or ``"python"`` (same algorithm interpreted; slow).
    settings
        ``max_memory`` bounds the tables.

    Raises
    ------
    FileFormatError
        Empty or binary input (but binary G-code), a move whose words are not numbers, a
        file cut off in the middle of a move, arcs that cannot be interpreted, a damaged
        binary G-code file.
    """
    if engine not in ("numba", "python"):
        raise InputError(f"unknown tokeniser engine {engine!r}; expected numba or python")
    _check_memory(len(data), path, settings)
    if data.startswith(_BGCODE_MAGIC):
        # binary G-code (.bgcode): read as its text form, the G-code then its metadata as the
        # comments a text file ends with (a damaged file is a FileFormatError naming the block)
        from gcode.bgcode import decode_bgcode

        data = decode_bgcode(data, path=path).text_form()
        _check_memory(len(data), path, settings)
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise FileFormatError(
            path, "this is UTF-16 text; save the G-code as ASCII or UTF-8", line=1
        )
    lex_lines, lex_words = lex(data, engine=engine)
    n = len(lex_lines["kind"])
    lines = np.empty(n, LINE_DTYPE)
    for k in LINE_FIELDS:
        lines[k] = lex_lines[k][:n]
    lines["layer"] = -1
    words = np.empty(len(lex_words["line"]), WORD_DTYPE)
    for k in WORD_FIELDS:
        words[k] = lex_words[k]
    starts = lex_lines["start"]

    _refuse_binary(data, lines, path)
    if not (lines["kind"] == KIND_COMMAND).any() and not (
        lines["kind"] == KIND_EXTENDED
    ).any():
        raise FileFormatError(
            path, "no G-code commands found (expected lines such as 'G1 X10 Y10')"
        )

    _refuse_bad_numbers(data, lines, words, path)
    info = scan_comments(data, starts)
    fl = _resolve_flavor(flavor, info)
    err, err_line, mv = run_machine(lex_lines, lex_words, flavor=fl, engine=engine)
    if err:
        _raise_move_error(data, lines, err, err_line, path)
    warnings = list(_truncation_checks(data, lines, info, path))

    moves = np.empty(len(mv["line"]), MOVE_DTYPE)
    for k, v in mv.items():
        moves[k] = v
    xy = (moves["x1"] != moves["x0"]) | (moves["y1"] != moves["y0"]) | (moves["kind"] >= 2)
    moves["is_extrusion"] = (moves["e"] > 0) & xy & np.isfinite(moves["x0"] + moves["y0"])
    mline = moves["line"]
    moves["feature"] = _forward_fill(info.feature_lines, info.feature_ids, mline, -1)
    moves["width"] = _forward_fill(info.width_lines, info.width_values, mline, np.nan)
    moves["wipe"] = _inside(info.wipe_start_lines, info.wipe_end_lines, mline)

    layers = _layers(info, moves, lines, n)
    return GCodeFile(
        path=path,
        data=data,
        lines=lines,
        words=words,
        moves=moves,
        layers=layers,
        features=info.feature_names,
        feature_categories=tuple(feature_category(f) for f in info.feature_names),
        dialect=info.dialect,
        slicer=info.slicer,
        flavor=fl,
        arcwelder=info.arcwelder,
        warnings=tuple(warnings),
    )


def _resolve_flavor(flavor: str, info: CommentInfo) -> str:
    if flavor != "auto":
        return FLAVORS.check(flavor)
    f = info.flavor or ""
    if f.startswith("marlin"):
        return "marlin"
    if f.startswith("klipper"):
        return "klipper"
    if f.startswith("reprap"):
        return "reprap"
    return "marlin" if not f else "generic"


def _refuse_binary(data: bytes, lines: np.ndarray, path: str) -> None:
    bad = np.flatnonzero(lines["control_column"] >= 0)
    if len(bad):
        i = int(bad[0])
        col = int(lines["control_column"][i])
        byte = data[lines["start"][i] + col]
        raise FileFormatError(
            path,
            f"binary data (byte 0x{byte:02x} at column {col + 1}) where text G-code was expected; "
            "this does not look like a G-code text file",
            line=i + 1,
        )
    # Lines that are neither G-code nor comments, in bulk, also mean junk.
    other = int((lines["kind"] == KIND_OTHER).sum())
    meaningful = int((lines["kind"] != KIND_BLANK).sum())
    if other > 10 and other > meaningful // 2:
        i = int(np.flatnonzero(lines["kind"] == KIND_OTHER)[0])
        raise FileFormatError(
            path,
            f"{other} of {meaningful} lines are neither G-code commands nor comments; "
            "this does not look like a G-code file",
            line=i + 1,
        )


#: Largest coordinate (mm, or degrees) and feed (mm/min) a move may carry: a kilometre and
#: 10 km/min are beyond any printer, and far below where float rounding or overflow begins.
MAX_COORDINATE = 1.0e6
MAX_FEED = 1.0e7
_MOTION_LETTERS = np.zeros(256, dtype=bool)
_MOTION_LETTERS[[ord(c) for c in "XYZEFIJRABCUVW"]] = True


def _refuse_bad_numbers(data: bytes, lines: np.ndarray, words: np.ndarray, path: str) -> None:
    """Refuse a move whose axis or feed word is not a plain finite number in range.

    Firmware read such words differently (Marlin skips a word without a number, ``Xnan``
    included; Klipper's ``float()`` takes ``Xnan`` as NaN and ``X1e309`` as infinity; our
    lexer, like Marlin's parser, splits ``1e309`` into X1 and E309), so no reading of them
    is safe.
    """
    if not len(words):
        return
    motion = ((lines["kind"] == KIND_COMMAND) & (lines["letter"] == ord("G"))
              & (lines["major"] >= 0) & (lines["major"] <= 3) & (lines["minor"] < 0))
    on = motion[words["line"]] & _MOTION_LETTERS[words["letter"]]
    if not on.any():
        return
    v = words["value"]
    # (a malformed word, "X1..5", is the state machine's error to report)
    valueless = (words["flags"] & WORD_VALUELESS) != 0
    malformed = (words["flags"] & WORD_MALFORMED) != 0
    with np.errstate(invalid="ignore"):
        limit = np.where(words["letter"] == ord("F"), MAX_FEED, MAX_COORDINATE)
        huge = ~valueless & ~malformed & ~(np.abs(v) <= limit)
    # "1e309": a number, then a lower-case e touching it (upper-case E touching a number is
    # compact G-code, X10E.5)
    first = np.r_[True, words["line"][1:] != words["line"][:-1]]
    touching = np.r_[False, words["start"][1:] == words["end"][:-1]] & ~first
    starts = np.clip(words["start"], 0, max(len(data) - 1, 0))
    exponent = touching & (np.frombuffer(data, np.uint8)[starts] == ord("e")) if len(data) \
        else np.zeros(len(words), bool)
    bad = on & (valueless | huge | exponent)
    if not bad.any():
        return
    k = int(np.flatnonzero(bad)[0])
    li = int(words["line"][k])
    letter = chr(words["letter"][k])
    if exponent[k]:
        what = ("a number in exponent notation (G-code numbers have none; firmware read it "
                "differently)")
    elif valueless[k]:
        what = (f"{letter} without a number (firmware disagree on it: Marlin skips the word, "
                f"Klipper reads '{letter}nan' as NaN)")
    else:
        unit = "mm/min" if letter == "F" else "mm"
        lim = MAX_FEED if letter == "F" else MAX_COORDINATE
        what = f"{letter} out of range (expected a finite number up to {lim:g} {unit})"
    msg = f"this move has {what}; found {_line_excerpt(data, lines, li)}"
    if li == len(lines) - 1 and not data.endswith((b"\n", b"\r")):
        msg = "the file ends in the middle of a line (truncated?): " + msg
    raise FileFormatError(path, msg, line=li + 1)


def _line_excerpt(data: bytes, lines: np.ndarray, li: int) -> str:
    """The start of line ``li`` quoted for a message (:func:`printability.errors.excerpt`),
    without copying the rest of a line that may be megabytes long."""
    s0, e0 = int(lines["start"][li]), int(lines["content_end"][li])
    return excerpt(data[s0:min(e0, s0 + EXCERPT_LENGTH + 1)])


def _raise_move_error(data, lines, err, li, path) -> None:
    msg = f"{ERR_MESSAGES[err]}; found {_line_excerpt(data, lines, int(li))}"
    if li == len(lines) - 1 and not data.endswith((b"\n", b"\r")):
        msg = "the file ends in the middle of a line (truncated?): " + msg
    raise FileFormatError(path, msg, line=int(li) + 1)


def _truncation_checks(data, lines, info, path):
    if len(lines) and not data.endswith((b"\n", b"\r")):
        last = lines[-1]
        if last["kind"] == KIND_COMMAND and last["letter"] == ord("G"):
            yield (
                f"{path}: the last line has no line terminator and is a move; "
                "the file may be truncated"
            )
    tail = max(0, len(data) - 300000)
    if data.find(b"; prusaslicer_config = begin", tail) >= 0 and (
        data.find(b"; prusaslicer_config = end", max(0, len(data) - 2000)) < 0
    ):
        raise FileFormatError(
            path,
            "the PrusaSlicer configuration block at the end starts but never ends: "
            "the file is truncated",
            line=len(lines),
        )
    if data.find(b"; CONFIG_BLOCK_START", tail) >= 0 and data.find(b"; CONFIG_BLOCK_END", tail) < 0:
        raise FileFormatError(
            path,
            "the BambuStudio/OrcaSlicer configuration block starts but never ends: "
            "the file is truncated",
            line=len(lines),
        )


def _forward_fill(event_lines, values, at_lines, default):
    """Value of the last event at or before each line (``default`` before the first)."""
    values = np.asarray(values)
    if len(event_lines) == 0:
        return np.full(len(at_lines), default, dtype=np.result_type(values, np.asarray(default)))
    k = np.searchsorted(event_lines, at_lines, side="right") - 1
    out = np.where(k >= 0, values[np.maximum(k, 0)], default)
    return out


def _inside(starts, ends, at_lines):
    if len(starts) == 0:
        return np.zeros(len(at_lines), bool)
    ev_lines = np.concatenate([starts, ends])
    ev_val = np.concatenate([np.ones(len(starts), bool), np.zeros(len(ends), bool)])
    order = np.argsort(ev_lines, kind="stable")
    return _forward_fill(ev_lines[order], ev_val[order], at_lines, False).astype(bool)


def _layers(info: CommentInfo, moves: np.ndarray, lines: np.ndarray, n_lines: int) -> np.ndarray:
    mline = moves["line"]
    ext = moves["is_extrusion"]
    if info.dialect == "zmoves":
        layer_lines, z, h = _layers_from_z(moves)
    else:
        layer_lines = info.layer_lines
        z = info.layer_z.copy()
        h = info.layer_height.copy()
    nlay = len(layer_lines)
    layers = np.zeros(nlay, LAYER_DTYPE)
    layers["line"] = layer_lines
    first_move = np.searchsorted(mline, layer_lines, side="left")
    layers["first_move"] = first_move
    layers["end_move"] = np.append(first_move[1:], len(moves)).astype(np.int64)
    move_layer = np.searchsorted(layer_lines, mline, side="right") - 1
    moves["layer"] = move_layer
    if nlay:
        counts = np.bincount(move_layer[ext & (move_layer >= 0)], minlength=nlay)
        layers["n_extrusions"] = counts[:nlay]
        # Z where the marker gives none: the top of the layer's first extrusion
        need = ~np.isfinite(z)
        if need.any():
            ez = np.full(nlay, np.nan)
            idx = np.flatnonzero(ext & (move_layer >= 0))
            if len(idx):
                lay = move_layer[idx]
                first = np.unique(lay, return_index=True)
                ez[first[0]] = moves["z1"][idx[first[1]]]
            z[need] = ez[need]
        if not np.isfinite(h).all():
            prev = np.concatenate([[0.0], z[:-1]])
            dz = z - prev
            # a layer without extrusion (NaN z) does not break the chain
            last = 0.0
            for k in range(nlay):
                if np.isfinite(z[k]):
                    dz[k] = z[k] - last
                    last = z[k]
            h = np.where(np.isfinite(h), h, dz)
    layers["z"] = z
    layers["height"] = h
    lines["layer"] = np.searchsorted(layer_lines, np.arange(n_lines), side="right") - 1
    return layers


def _layers_from_z(moves: np.ndarray, eps: float = 1e-4):
    """Layer boundaries of a file without layer comments.

    A layer is a run of extrusions at one Z. A new one starts when an
    extrusion begins at another Z than the previous extrusion ended (the
    nozzle moved in Z in between), and, for spiral (vase) printing where Z
    rises *while* extruding, when rising extrusion follows flat extrusion or
    when a rising extrusion starts one flat-layer step above where the
    spiral layer began. The layer's first line is the first Z-changing move after the
    previous layer's last extrusion (the lift or the move to the new height),
    or its first extrusion when there is none. Its Z is the highest Z reached
    while extruding in it.
    """
    ext = np.flatnonzero(moves["is_extrusion"])
    if len(ext) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    z0 = moves["z0"][ext].tolist()
    z1 = moves["z1"][ext].tolist()
    starts: list[int] = []  # index into ext of each layer's first extrusion
    zs: list[float] = []
    base = prev_end = nominal = float("nan")
    spiral = False  # the current layer has risen while extruding
    for k in range(len(ext)):
        a, b = z0[k], z1[k]
        flat = abs(b - a) <= eps
        if not starts or abs(a - prev_end) > eps:
            new = True
        elif not flat:
            new = not spiral or (nominal == nominal and a - base >= nominal - eps)
        else:
            new = False
        if new:
            if starts and flat and not spiral and a - zs[-1] > eps:
                nominal = a - zs[-1]
            base = base + nominal if (spiral and not flat and abs(a - prev_end) <= eps) else a
            starts.append(k)
            zs.append(max(a, b))
            spiral = False
        else:
            zs[-1] = max(zs[-1], b)
        spiral = spiral or not flat
        prev_end = b
    mz0 = moves["z0"]
    mz1 = moves["z1"]
    layer_lines = np.empty(len(starts), np.int64)
    prev_last = -1
    for j, k in enumerate(starts):
        first_ext = int(ext[k])
        mv = first_ext
        if j > 0:
            lo = prev_last + 1
            dz = np.flatnonzero(np.abs(mz1[lo:first_ext] - mz0[lo:first_ext]) > eps)
            if len(dz):
                mv = lo + int(dz[0])
        layer_lines[j] = moves["line"][mv]
        nxt = starts[j + 1] if j + 1 < len(starts) else len(ext)
        prev_last = int(ext[nxt - 1])
    z = np.array(zs)
    h = np.diff(np.concatenate([[0.0], z]))
    return layer_lines, z, h
