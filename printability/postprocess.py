"""Post-process a slicer's G-code for a nozzle on a machine with a rotary axis.

The slicer's XY paths are kept; for every extruding move of the part the
nozzle orientation is chosen so that the swept footprint stays inside the
layer's target (the MMC promise, see :mod:`printability.motion.orientation`)
and the bead width matches the slicer's planned width where possible. What
no orientation can print is cut away and reported per layer. Every line that
needs no change is kept byte for byte; the changes are:

* a rotary word (``C…``) folded into the travel move before an extrusion
  that needs another orientation (feed policy ``xy``), or a rotation-only
  line ``G1 C…`` without E inserted just before it (policy ``euclidean``,
  or no travel to fold it into). Inserted lines carry no F: the firmware
  turns at the current feed rate read as °/min, and the modal feed the
  slicer set is never disturbed;
* extruding arcs (G2/G3) of the part are linearised into G1 chords when the
  nozzle is not round (a rotary word is never put on an arc);
* a move that fits only in part is replaced by its printable pieces (with
  their share of E) joined by non-extruding moves; a move that fits nowhere
  becomes a non-extruding move. In absolute-E files a ``G92 E…`` restores
  the E coordinate the next slicer line expects;
* with ``e_policy="width"`` (default) and a non-round nozzle, E is scaled by
  the ratio of the bead cross-sections (laid width / planned width, Slic3r's
  rounded-rectangle model) where the width laid differs from the plan;
* a comment block (the nozzle, the machine, the version and the per-layer
  summary) is inserted before the first command; it also marks the file so
  it is never processed twice.

The layer target G is rebuilt from the slicer's own part extrusions exactly
as ``printability analyze`` does (:func:`printability.sources.gcode.layer_regions`:
supports, skirt, brim, wipe tower, custom/purge moves and ironing excluded;
every chord swept by a disk of half its planned width, the ``;WIDTH:``
comments or the width inverted from E). The outer perimeter's centre line is
therefore exactly w/2 from ∂G; ``tolerance`` (default 1 µm, minus the
rounding of the coordinates written) absorbs the rounding of coordinates and
of the polygonal arcs. Footprints are tested against G grown by that
tolerance. By default (``interior``) G is the object, not only its beads: the
gaps the slicer leaves inside it (sparse infill) are filled back, the holes its
outer walls trace kept (:func:`printability.sources.gcode.fill_interior`), so a
footprint may reach into a gap (inside the part) instead of turning standing
still; that target is built by GEOS per layer. With ``interior=False`` it is the
union of one convex polygon per bead (:mod:`printability.motion.beadunion`:
between G ⊕ 0.35τ and G ⊕ τ, without a GEOS overlay; built by
:mod:`printability.targets`). Layers are planned in
batches, laid side by side in one plane (:mod:`printability.motion.tiles`) so
that one union and one planner call serve a batch. Non-part moves are left as
they are.

A round nozzle no larger than the one the file was sliced for (the slicer's
``nozzle_diameter``) lays the slicer's own beads, each inside G by
construction: such a file only gets the comment block. A larger round nozzle,
or any other shape, is checked move by move with its whole orifice.
"""

from __future__ import annotations

import contextvars
import math
import os
import re
import stat
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from gcode import MF_E_RELATIVE, NON_PART_CATEGORIES, parse_gcode
from gcode.bgcode import (
    GCODE_ENCODINGS,
    PRINT_METADATA,
    PRINTER_METADATA,
    BinaryGCode,
    decode_bgcode,
    encode_bgcode,
    is_bgcode,
    rescaled_metadata,
)
from gcode.dialects import INTERIOR_CATEGORIES
from gcode.flavors import RotaryAxis
from gcode.printtime import PrintTime, estimate_print_time, format_duration
from gcode.writer import WriterOptions, format_number, header_lines
from printability import __version__
from printability._arrays import take_rows
from printability.base.files import replace_file
from printability.errors import (
    FileFormatError,
    InputError,
    NozzleTooLargeError,
    PrintabilityOSError,
    ResourceError,
    excerpt,
)
from printability.machine import Machine, parse_machine
from printability.motion.orientation import (
    OrientationOptions,
    PieceMap,
    plan_orientations,
)
from printability.nozzle import Nozzle, parse_nozzle
from printability.options import E_POLICIES, FEED_POLICIES
from printability.rewrite import eol_of, first_command_line, rewrite
from printability.settings import DEFAULT_SETTINGS
from printability.targets import layer_targets

__all__ = [
    "PROCESSED_KEY",
    "LayerReport",
    "PostprocessOptions",
    "PostprocessResult",
    "already_processed",
    "postprocess_bytes",
    "postprocess_file",
    "settings_from_environment",
]

_PROCESSED = re.compile(rb"; printability \S+ postprocessed this file")


def _check_range(name: str, value: float, lo: float, hi: float, unit: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (lo <= value <= hi):
        unit = " " + unit if unit else ""
        raise InputError(f"{name} expects a number from {lo:g} to {hi:g}{unit}; "
                         f"found {excerpt(str(value))}")


def _check_output_name(name: str) -> None:
    """A file name for the slicer to give its output: one name, no folder, no control
    character (the slicer renames its file to it; ``../../x`` would move it elsewhere)."""
    bad = (not name or name in (".", "..") or "/" in name or "\\" in name
           or any(ord(c) < 32 or ord(c) == 127 for c in name)
           or len(name.encode("utf-8")) > 255)
    if bad:
        shown = name[:60].encode("unicode_escape").decode("ascii")
        raise InputError(f"output name expects a file name (no folder, no control characters, "
                         f"at most 255 bytes); found {shown!r}")


@dataclass(frozen=True)
class PostprocessOptions:
    """What to post-process for.

    Attributes
    ----------
    nozzle
        Nozzle SPEC or object; None: a round nozzle of the slicer's
        ``nozzle_diameter`` (SLIC3R_NOZZLE_DIAMETER).
    machine
        Machine SPEC or object (default ``ttr``: a full-turn rotary C axis).
    tolerance
        How far a swept footprint may stand outside the target, mm.
    feed_policy
        Overrides the machine's; one of ``xy`` or ``euclidean``
        (``inverse-time`` needs an F on every move, which would rewrite
        every line: use ``printability generate``).
    letter
        Overrides the machine's rotary letter.
    unwind
        Cabled head: bring the axis back towards 0 on travel moves.
    e_policy
        One of :data:`printability.options.E_POLICIES`.
    filament_diameter, layer_height
        Override what the file or the slicer's environment says, mm.
    angle_decimals
        Precision of rotary words.
    chord_tolerance
        Linearisation of arcs, mm.
    workers
        Threads that rebuild the layer targets (compiled kernels and GEOS
        release the GIL) while the planner runs, and that the planner's footprint
        tests are shared out over; None: one per CPU core, at most 4. The output
        is the same bytes on any number.
    interior
        Plan against the object: the slicer's beads with the gaps it leaves inside the object
        (sparse infill) filled back (:func:`printability.sources.gcode.fill_interior`), so a
        footprint may reach into a gap it would not leave the part through. False: against
        the beads alone (the nozzle never covers a spot the slicer leaves empty; more turns
        standing still, and a slower print).
    allow_empty
        Write the file even when the nozzle prints none of the part (by default
        that is a :class:`NozzleTooLargeError` and the file is left alone).
    output_name
        New final file name to hand back to the slicer through the
        ``<gcode>.output_name`` file (PrusaSlicer ≥ 2.4 convention); None
        leaves the name alone.
    """

    nozzle: str | Nozzle | None = None
    machine: str | Machine = "ttr"
    tolerance: float = 1e-3
    feed_policy: str | None = None
    letter: str | None = None
    unwind: bool = False
    e_policy: str = "width"
    filament_diameter: float | None = None
    layer_height: float | None = None
    angle_decimals: int = 3
    chord_tolerance: float = 0.002
    output_name: str | None = None
    workers: int | None = None
    orientation: OrientationOptions = field(default_factory=OrientationOptions)
    allow_empty: bool = False
    interior: bool = True

    def __post_init__(self) -> None:
        if self.output_name is not None:
            _check_output_name(self.output_name)
        _check_range("tolerance", self.tolerance, 0.0, 1.0, "mm")
        _check_range("chord tolerance", self.chord_tolerance, 1e-6, 1.0, "mm")
        _check_range("angle decimals", self.angle_decimals, 0, 9, "")
        for key, value in (("filament diameter", self.filament_diameter),
                           ("layer height", self.layer_height)):
            if value is not None:
                _check_range(key, value, 1e-3, 100.0, "mm")


@dataclass(frozen=True)
class LayerReport:
    """What post-processing did to one layer (lengths in mm, areas in mm²)."""

    index: int
    z: float
    target_area: float
    moves: int
    turned: int
    split_moves: int
    dropped_moves: int
    dropped_length: float
    dropped_area: float
    printed_length: float


@dataclass(frozen=True)
class PostprocessResult:
    """Outcome of a post-processing run."""

    path: str
    output: str
    already_processed: bool
    # print_time_in / print_time_out: seconds Klipper's planner takes for the slicer's file
    # and for the rewritten one with the machine's limits (gcode.printtime), None when not
    # estimated; filament_in / filament_out: mm of filament the extruding moves push, before
    # and after; binary: what the binary G-code's G-code blocks are (compression, encoding),
    # None for text G-code
    lines_in: int
    lines_out: int
    changed_lines: int
    inserted_lines: int
    rotary_words: int
    layers: tuple[LayerReport, ...]
    elapsed: float
    nozzle: str
    machine: str
    notes: tuple[str, ...] = ()
    print_time_in: float | None = None
    print_time_out: float | None = None
    filament_in: float | None = None
    filament_out: float | None = None
    binary: str | None = None

    @property
    def dropped_moves(self) -> int:
        return sum(r.dropped_moves for r in self.layers)

    @property
    def split_moves(self) -> int:
        return sum(r.split_moves for r in self.layers)

    @property
    def dropped_length(self) -> float:
        return sum(r.dropped_length for r in self.layers)


# ----------------------------------------------------------------- environment


def _env_float(env: Mapping[str, str], key: str) -> float | None:
    """First number of a SLIC3R_* value (per-extruder values are comma separated)."""
    raw = env.get(key)
    if raw is None or not raw.strip():
        return None
    first = raw.split(",")[0].strip().rstrip("%")
    try:
        value = float(first)
    except ValueError:
        raise InputError(f"environment variable {key}={excerpt(raw)}: expected a number") from None
    return value


def settings_from_environment(env: Mapping[str, str] | None = None) -> dict[str, object]:
    """The slicer settings a PrusaSlicer-family slicer exports to its scripts.

    PrusaSlicer, SuperSlicer and OrcaSlicer export every print setting as an
    environment variable ``SLIC3R_<KEY>`` (upper case; vectors comma
    separated, one value per extruder) and ``SLIC3R_PP_OUTPUT_NAME`` (the
    final name of the file). Recognised here: ``NOZZLE_DIAMETER``,
    ``LAYER_HEIGHT``, ``FILAMENT_DIAMETER``, ``EXTRUSION_WIDTH``,
    ``PERIMETER_EXTRUSION_WIDTH``, ``EXTERNAL_PERIMETER_EXTRUSION_WIDTH``,
    ``USE_RELATIVE_E_DISTANCES``, ``ARC_FITTING`` (PrusaSlicer ≥ 2.6) /
    ``ENABLE_ARC_FITTING`` (OrcaSlicer), ``GCODE_FLAVOR``, ``PP_OUTPUT_NAME``.

    Returns
    -------
    dict
        Only the keys found, with lower-case names (``nozzle_diameter``...).
    """
    env = os.environ if env is None else env
    out: dict[str, object] = {}
    for key in ("NOZZLE_DIAMETER", "LAYER_HEIGHT", "FILAMENT_DIAMETER", "EXTRUSION_WIDTH",
                "PERIMETER_EXTRUSION_WIDTH", "EXTERNAL_PERIMETER_EXTRUSION_WIDTH"):
        v = _env_float(env, "SLIC3R_" + key)
        if v is not None:
            out[key.lower()] = v
    rel = env.get("SLIC3R_USE_RELATIVE_E_DISTANCES")
    if rel is not None and rel.strip():
        out["use_relative_e_distances"] = rel.strip().lower() in ("1", "true", "yes")
    arc = env.get("SLIC3R_ARC_FITTING") or env.get("SLIC3R_ENABLE_ARC_FITTING")
    if arc is not None and arc.strip():
        out["arc_fitting"] = arc.strip().lower() not in ("0", "false", "disabled", "no")
    for key in ("GCODE_FLAVOR", "PP_OUTPUT_NAME"):
        if env.get("SLIC3R_" + key):
            out[key.lower()] = env["SLIC3R_" + key]
    return out


def already_processed(data: bytes) -> bool:
    """True when printability's marker comment is in the file (binary G-code: in its G-code,
    or its print metadata say so)."""
    if is_bgcode(data):
        try:
            return _binary_processed(decode_bgcode(data))
        except FileFormatError:
            return False
    return _first_at_line_start(data, b"; printability ", _PROCESSED) is not None


_BLANK = frozenset(b" \t\n\r\x0b\x0c")  # what \s matches in a bytes pattern


def _first_at_line_start(data: bytes, word: bytes, pattern: re.Pattern, *,
                         comment: bool = False) -> re.Match | None:
    """The first match of ``pattern`` at a line start (``re.search`` with ``^`` and
    ``re.MULTILINE``), for a pattern that is ``word`` and more (``comment``: ``;``, blanks,
    then ``word`` and more).

    The occurrences of ``word`` are found with ``bytes.find`` (a scan in C) and the pattern
    is tried only at the line start before each: a regular-expression scan tries every
    position of the file (tens of ms on a 3 MB file). A match's start is determined by its
    ``word``, and moves on with it, so the first occurrence that matches gives the first
    match.
    """
    pos = data.find(word)
    while pos >= 0:
        s = pos
        if comment:
            s -= 1
            while s >= 0 and data[s] in _BLANK:
                s -= 1
            ok = s >= 0 and data[s] == 59  # ";"
        else:
            ok = True
        if ok and (s == 0 or data[s - 1] == 10):
            m = pattern.match(data, s)
            if m is not None:
                return m
        pos = data.find(word, pos + 1)
    return None


def _config_value(data: bytes, key: str) -> float | None:
    """A number from the slicer's configuration comments (``; key = value``)."""
    kb = key.encode()
    m = _first_at_line_start(data, kb, re.compile(rb";\s*" + re.escape(kb)
                                                  + rb"\s*=\s*([-+0-9.eE]+)"), comment=True)
    if not m:
        return None
    try:
        return float(m.group(1))
    except ValueError:
        return None


# ----------------------------------------------------------------- layer targets


#: ``on_progress(stage, done, total)`` of the run under way (:func:`postprocess_file`'s
#: ``on_progress``); ``total`` 0 when the stage has no count
ProgressCallback = Callable[[str, int, int], None]
_PROGRESS: contextvars.ContextVar[ProgressCallback | None] = contextvars.ContextVar(
    "printability_postprocess_progress", default=None)


def _progress(stage: str, done: int = 0, total: int = 0) -> None:
    """Tell the run's ``on_progress`` (if any) which stage it is in and how far."""
    report = _PROGRESS.get()
    if report is not None:
        report(stage, done, total)


def _counted(batches: Iterator[tuple], total: int) -> Iterator[tuple]:
    """``batches`` of :func:`printability.targets.layer_targets`, each reported as planned
    when the next one is asked for (a batch's first item is its layers)."""
    done = 0
    _progress("planning the layers", 0, total)
    for batch in batches:
        yield batch
        done += len(batch[0])
        _progress("planning the layers", done, total)


def _part_mask(g) -> np.ndarray:
    """Extrusions that belong to the part (not skirt, support, purge, wipe...)."""
    m = g.moves
    return m["is_extrusion"] & ~g.moves_in(NON_PART_CATEGORIES) & ~m["wipe"] & (m["layer"] >= 0)


def _interior_mask(g, seg_move: np.ndarray) -> np.ndarray:
    """Per chord, True where its feature's bead edges are not the part's surface
    (:data:`gcode.dialects.INTERIOR_CATEGORIES`)."""
    return g.moves_in(INTERIOR_CATEGORIES)[seg_move]


def postprocess_bytes(
    data: bytes,
    *,
    path: str = "<bytes>",
    options: PostprocessOptions = PostprocessOptions(),
    env: Mapping[str, str] | None = None,
) -> tuple[bytes, PostprocessResult]:
    """Post-process G-code bytes; see the module docstring.

    Binary G-code (``.bgcode``, recognised by its content) comes back as binary G-code:
    see :func:`_postprocess_binary`.

    Returns
    -------
    (bytes, PostprocessResult)
        The new content (the input itself when it was already processed).

    Raises
    ------
    FileFormatError, InputError
        Unreadable G-code (a damaged binary file among them), bad options.
    """
    if is_bgcode(data):
        return _postprocess_binary(data, path=path, options=options, env=env)
    t_start = time.perf_counter()
    envs = settings_from_environment(env if env is not None else {})
    if already_processed(data):
        n = data.count(b"\n")
        res = PostprocessResult(path, path, True, n, n, 0, 0, 0, (), 0.0, "", "",
                                ("already post-processed by printability: left unchanged",))
        return data, res

    machine = parse_machine(options.machine)
    if options.nozzle is None:
        d = envs.get("nozzle_diameter") or _config_value(data, "nozzle_diameter")
        if d is None:
            raise InputError(f"{path}: no nozzle given: pass --nozzle SPEC (e.g. "
                             "ellipse:major=0.8,minor=0.3); the slicer's nozzle_diameter was not "
                             "found either")
        nozzle = parse_nozzle(f"circle:d={format_number(float(d), 4)}")
    else:
        nozzle = parse_nozzle(options.nozzle)
    _progress("reading the G-code")
    g = parse_gcode(data, path=path)
    # the machine's flavor, else the one the slicer wrote the file for
    flavor = machine.firmware(g.flavor)
    policy = FEED_POLICIES.check(options.feed_policy or machine.feed_policy_for(flavor))
    if policy == "inverse-time":
        raise InputError(
            f"{path}: feed policy inverse-time (G93) needs an F word on every move, so every "
            "line of the slicer's file would change; post-processing keeps the slicer's lines. "
            "Use feed policy xy or euclidean, or 'printability generate'"
        )
    e_policy = E_POLICIES.check(options.e_policy)
    letter = (options.letter or machine.rotary_letter).upper()
    fd = (options.filament_diameter or envs.get("filament_diameter")
          or _config_value(data, "filament_diameter") or machine.filament_diameter)

    moves = g.moves
    lines = g.lines
    n_layers = len(g.layers)
    heights = g.layers["height"].copy() if n_layers else np.zeros(0)
    if options.layer_height is not None:
        heights[:] = options.layer_height
    heights = np.where(np.isfinite(heights) & (heights > 0), heights,
                       envs.get("layer_height") or 0.2)
    if moves.size and (moves["flags"] & 4).any():
        raise FileFormatError(path, "the file uses inches (G20); only millimetre G-code is "
                              "supported", line=int(moves["line"][(moves["flags"] & 4) > 0][0]) + 1)

    quad_segs = 32
    # A round nozzle no larger than the one the file was sliced for lays the slicer's
    # own beads: each is inside G by construction (G is their union), so nothing moves.
    slicer_d = envs.get("nozzle_diameter") or _config_value(data, "nozzle_diameter")
    if slicer_d is None:
        # the file does not say (Cura's, or a settings block cut off): the beads it plans are
        # about its nozzle's width (Cura's lines are the nozzle's size, PrusaSlicer's 1.05-1.1x)
        ext = moves["is_extrusion"]
        planned = moves["width"][ext & np.isfinite(moves["width"])]
        if not planned.size and ext.any():
            # no width comments (Cura): the widths its E gives
            from gcode.rotary import width_from_e

            mm = moves[ext]
            length = np.hypot(mm["x1"] - mm["x0"], mm["y1"] - mm["y0"])
            h = np.where(mm["layer"] >= 0, heights[np.maximum(mm["layer"], 0)], 0.2) \
                if len(heights) else np.full(len(mm), 0.2)
            ok = length > 1e-6
            planned = width_from_e(mm["e"][ok] / length[ok], h[ok], float(fd))
        slicer_d = float(np.median(planned)) if planned.size else 0.0
    narrow_beads = bool(nozzle.is_round and 2 * nozzle.footprints[0].a <= slicer_d + 1e-9)
    if not narrow_beads:
        _check_memory(len(data), path, planned=True)  # before the plan grows
    period = nozzle.symmetry_period
    turns = machine.turns(nozzle)
    wopts = WriterOptions(letter=letter, period=period if turns else 0.0,
                          angle_min=machine.angle_min if machine.has_rotary else 0.0,
                          angle_max=machine.angle_max if machine.has_rotary else 0.0,
                          unwind=options.unwind, feed_policy=policy,
                          rotary_feed=machine.rotary_axis.rotation_feed,
                          filament_diameter=float(fd), angle_decimals=options.angle_decimals)
    if machine.full_turn and not options.unwind:
        # a full-turn axis without cables turns freely: no limits on the coordinate
        wopts = WriterOptions(**{**wopts.__dict__, "angle_min": -math.inf,
                                 "angle_max": math.inf})

    n_workers = _workers(options)
    part = _part_mask(g)
    part_idx = np.flatnonzero(part)
    seg = g.segments(moves=take_rows(moves, part_idx)) if part_idx.size and not narrow_beads else \
        np.zeros(0, dtype=[("x0", "f8"), ("y0", "f8"), ("x1", "f8"), ("y1", "f8"),
                           ("e", "f8"), ("move", "i8")])
    # new lines are rounded to 4 decimals: keep that displacement inside the tolerance
    tol_grow = options.tolerance - wopts.rounding
    seg_len = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"]) if len(seg) else np.zeros(0)
    if part_idx.size and not narrow_beads:
        seg_move = part_idx[seg["move"]]  # index into g.moves
        widths = _planned_widths(g, seg, seg_move, float(fd))
        seg_interior = _interior_mask(g, seg_move)
        seg_layer = moves["layer"][seg_move]
        order = np.argsort(seg_layer, kind="stable")
        bounds = np.searchsorted(seg_layer[order], np.arange(n_layers + 1))
        batches = layer_targets(g, float(fd), quad_segs, tol_grow, workers=n_workers,
                                 planned=(seg, order, bounds), reach=nozzle.radius,
                                 interior=options.interior)
    else:
        seg_move = np.zeros(0, np.int64)
        widths = np.zeros(0)
        seg_interior = np.zeros(0, dtype=bool)
        order = np.zeros(0, np.int64)
        bounds = np.zeros(n_layers + 1, np.int64)
        batches = iter(())
    if part_idx.size and not narrow_beads:
        batches = _counted(batches, n_layers)

    # ---- plan every layer: batches of layers side by side, one target per batch
    seg_angle = np.zeros(len(seg))
    seg_fold = np.zeros(len(seg), dtype=bool)
    seg_width_laid = np.full(len(seg), np.nan)
    split_found: list[np.ndarray] = []  # the split chords, per batch
    rows_found: list[tuple] = []  # their pieces as arrays, per batch
    reports: list[LayerReport] = []
    prev = 0.0
    for layers, offset, tgt, areas, last in batches:
        rows = [order[bounds[k]:bounds[k + 1]] for k in layers]
        counts = np.array([r.size for r in rows], dtype=np.int64)
        idx = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        lay_of = np.repeat(np.arange(len(layers)), counts)
        plan = None
        if idx.size:
            p0 = np.column_stack([seg["x0"][idx], seg["y0"][idx]]) + offset[lay_of]
            p1 = np.column_stack([seg["x1"][idx], seg["y1"][idx]]) + offset[lay_of]
            sm = seg_move[idx]
            chained = np.zeros(idx.size, dtype=bool)
            if idx.size > 1 and policy == "xy":
                same = (sm[1:] == sm[:-1]) | ((sm[1:] == sm[:-1] + 1)
                                              & (np.abs(p0[1:] - p1[:-1]).max(axis=1) < 1e-9))
                chained[1:] = same & (lay_of[1:] == lay_of[:-1])
            plan = plan_orientations(p0, p1, widths[idx], tgt, nozzle, machine,
                                     options=options.orientation, previous=prev,
                                     prepared_target=tgt, chained=chained,
                                     narrow_beads=narrow_beads, fold_pieces=policy == "xy",
                                     interior=seg_interior[idx],
                                     # the cores are the targets' until the last is built
                                     workers=n_workers if last else 1)
            seg_angle[idx] = plan.angle
            seg_fold[idx] = plan.fold
            seg_width_laid[idx] = plan.width
            if plan.pieces:
                split_found.append(idx[np.fromiter(plan.pieces, np.int64, len(plan.pieces))])
                rows_found.append((idx[plan.piece_rows[0]], *plan.piece_rows[1:],
                                   plan.piece_fold))
            finite = plan.angle[np.isfinite(plan.angle)]
            if finite.size:
                prev = float(finite[-1])
        reports.extend(_layer_reports(g, layers, areas, idx, counts, lay_of, plan, seg_len,
                                      widths))

    # ---- rewrite
    piece_rows = None
    piece_fold = None
    seg_pieces: Mapping[int, list] = {}
    if rows_found:
        cols = [np.concatenate([r[c] for r in rows_found]) for c in range(5)]
        by_chord = np.argsort(cols[0], kind="stable")
        piece_rows = tuple(c[by_chord] for c in cols[:4])
        piece_fold = cols[4][by_chord]
        seg_pieces = PieceMap(np.concatenate(split_found), piece_rows)
    # an interior bead laid wider than planned keeps the slicer's volume: E follows the
    # width only where it is narrower (a wider footprint spreads the same bead)
    with np.errstate(invalid="ignore"):
        width_for_e = np.where(seg_interior & (seg_width_laid > widths)
                               & options.orientation.wider_interior, widths, seg_width_laid)
    _progress("rewriting the moves")
    out, turned_per_layer = rewrite(g, data, moves, seg, seg_move, seg_angle, seg_fold,
                                    width_for_e, seg_pieces, widths, heights, wopts, turns,
                                    e_policy, nozzle, piece_rows=piece_rows,
                                    piece_fold=piece_fold)
    reports = [LayerReport(**{**r.__dict__, "turned": turned_per_layer.get(r.index, 0)})
               for r in reports]
    summary = [{"z": r.z, "target_area": r.target_area, "lost_area": r.dropped_area,
                "dropped_moves": r.dropped_moves, "dropped_length": r.dropped_length,
                "split_moves": r.split_moves} for r in reports]
    notes = [
        "lost area = dropped length x planned width (what no orientation can print)",
        f"tolerance = {options.tolerance:g} mm; E policy = {e_policy}; layer targets from the "
        "slicer's part extrusions" + (", the gaps inside the object filled" if options.interior
                                      else ""),
    ]
    if narrow_beads:
        notes.append("round nozzle no larger than the slicer's: it lays the slicer's own beads, "
                     "every move is kept as it is")
    axis = RotaryAxis(**{**machine.rotary_axis.__dict__, "letter": letter})
    if turns:
        notes.append(flavor.rotary_setup_note(axis))
    # the print time on the firmware's planner, before and after (the body has no header
    # yet; comments take no time)
    _progress("estimating the print time")
    t_in = estimate_print_time(g, limits=machine.planner, rotary=axis)
    g_out = parse_gcode(b"".join(out.chunks), path=path) if out.rotary_words or out.changed \
        else g
    t_out = estimate_print_time(g_out, limits=machine.planner, rotary=axis) \
        if g_out is not g else t_in
    notes.append(print_time_note(t_in.total, t_out))
    head = header_lines(version=__version__, nozzle=nozzle.spec, machine=machine.spec,
                        options=wopts, mode="postprocessed", summary=summary, notes=notes,
                        flavor=flavor.name, e_mode=_e_mode(moves))
    if turns:
        # the axis declared (Klipper registers it) and zeroed before any rotary word
        head += flavor.declare_rotary(axis)
    first_cmd = first_command_line(lines)
    eol = eol_of(g.line(first_cmd)) if len(lines) else b"\n"
    block = b"".join(h.encode("utf-8") + eol for h in head)
    body = out.chunks
    body.insert(first_cmd, block)
    result_bytes = b"".join(body)
    n_part = sum(r.moves for r in reports)
    # (printed_length is a difference of sums: a few 1e-13 mm when nothing is printed)
    if n_part and not options.allow_empty and \
            not any(r.printed_length > 1e-6 for r in reports):
        raise NozzleTooLargeError(
            f"{path}: nozzle {nozzle.spec} on machine {machine.spec} can print none of the "
            f"part's {n_part} extrusions (every feature is narrower than the nozzle lays at any "
            "orientation); the file is left unchanged. Choose a smaller nozzle, or pass "
            "--allow-empty to write it anyway")
    elapsed = time.perf_counter() - t_start
    res = PostprocessResult(
        path=path, output=path, already_processed=False, lines_in=len(lines),
        lines_out=len(lines) + out.inserted + len(head), changed_lines=out.changed,
        inserted_lines=out.inserted + len(head), rotary_words=out.rotary_words,
        layers=tuple(reports), elapsed=elapsed, nozzle=nozzle.spec, machine=machine.spec,
        notes=tuple(notes), print_time_in=t_in.total, print_time_out=t_out.total,
        filament_in=_filament(g.moves), filament_out=_filament(g_out.moves),
    )
    return result_bytes, res


def _filament(moves: np.ndarray) -> float:
    """mm of filament the extruding moves push."""
    return float(moves["e"][moves["is_extrusion"]].sum())


# ----------------------------------------------------------------- binary G-code

#: Print-metadata key that marks a binary file whose G-code encoding drops comments
#: (MeatPack without comments), where the comment block cannot say it was post-processed
PROCESSED_KEY = "postprocessed by"


def _binary_processed(doc: BinaryGCode) -> bool:
    marked = doc.value(PROCESSED_KEY)
    return (marked is not None and marked.startswith("printability")) or \
        already_processed(doc.gcode)


def _postprocess_binary(
    data: bytes,
    *,
    path: str,
    options: PostprocessOptions,
    env: Mapping[str, str] | None,
) -> tuple[bytes, PostprocessResult]:
    """Post-process binary G-code: binary G-code in, binary G-code out.

    The file is decoded (:func:`gcode.bgcode.decode_bgcode`: every block's CRC checked) to
    its text form, the G-code followed by the metadata as the comments a text file ends with
    (the slicer, its flavor and nozzle are read there as from a text file); that text goes
    through :func:`postprocess_bytes`, and its G-code part is encoded back
    (:func:`gcode.bgcode.encode_bgcode`): the G-code blocks it leaves as they were and every
    thumbnail and metadata block are kept byte for byte, the rest re-encoded with the file's
    own compression and encoding. The metadata PrusaSlicer derives from the G-code are
    updated in the print and printer metadata (:func:`gcode.bgcode.rescaled_metadata`):
    the estimated printing times by the ratio of the print times the firmware's planner
    gives the new and the old G-code, the filament used and its cost by the ratio of the
    filament the extruding moves push. Line numbers in messages are those of the G-code.
    """
    t_start = time.perf_counter()
    doc = decode_bgcode(data, path=path)
    _check_memory(len(doc.gcode), path, binary=True)
    n_in = doc.gcode.count(b"\n")
    if _binary_processed(doc):
        res = PostprocessResult(path, path, True, n_in, n_in, 0, 0, 0, (), 0.0, "", "",
                                ("already post-processed by printability: left unchanged",),
                                binary=doc.describe())
        return data, res
    trailer = doc.trailer()
    new_text, res = postprocess_bytes(doc.gcode + trailer, path=path, options=options, env=env)
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


def print_time_note(t_in: float, out: PrintTime) -> str:
    """One line on the print time before and after, and what the turns cost."""
    text = (f"estimated print time on the firmware's planner (Klipper's look-ahead, the "
            f"machine's [planner] limits): slicer's file {format_duration(t_in)}, this file "
            f"{format_duration(out.total)}")
    if t_in > 0:
        text += f" ({out.total / t_in:.2f}x)"
    if out.rotation_only:
        text += (f"; {out.rotation_only} rotation-only moves take "
                 f"{format_duration(out.rotation_only_time)}, each a full stop")
    return text


def _e_mode(moves: np.ndarray) -> str:
    """How the file's extruding moves count E: ``relative``, ``absolute`` or ``mixed``."""
    rel = (moves["flags"][moves["e"] > 0] & MF_E_RELATIVE) != 0
    if rel.all():
        return "relative"
    return "absolute" if not rel.any() else "mixed"


def _layer_reports(g, layers, areas, idx, counts, lay_of, plan, seg_len, widths
                   ) -> list[LayerReport]:
    """What the plan of a batch did to each of its layers (``idx``: the batch's chords,
    ``counts`` per layer, ``lay_of`` the layer of each within the batch)."""
    from printability.motion._plan_kernels import piece_losses

    n = len(layers)
    split = np.zeros(n, np.int64)
    dropped = np.zeros(n, np.int64)
    d_len = np.zeros(n)
    d_area = np.zeros(n)
    if plan is not None and plan.pieces:
        keys = np.fromiter(plan.pieces, dtype=np.int64, count=len(plan.pieces))
        rows = plan.piece_rows
        row_move = np.asarray(rows[0], np.int64)
        split, dropped, d_len, d_area = piece_losses(
            keys, np.searchsorted(row_move, keys, "left"),
            np.searchsorted(row_move, keys, "right"), np.asarray(rows[1], float),
            np.asarray(rows[2], float), np.asarray(lay_of, np.int64),
            np.asarray(seg_len[idx[keys]], float), np.asarray(widths[idx[keys]], float), n)
    d_len = d_len.tolist()
    d_area = d_area.tolist()
    starts = np.concatenate([[0], np.cumsum(counts)])
    return [LayerReport(
        index=k, z=float(g.layers["z"][k]), target_area=areas[j], moves=int(counts[j]),
        turned=0, split_moves=int(split[j]), dropped_moves=int(dropped[j]),
        dropped_length=d_len[j], dropped_area=d_area[j],
        printed_length=float(seg_len[idx[starts[j]:starts[j + 1]]].sum()) - d_len[j],
    ) for j, k in enumerate(layers)]


def _workers(options: PostprocessOptions) -> int:
    if options.workers is not None:
        if options.workers < 1:
            raise InputError(f"workers must be at least 1; got {options.workers!r}")
        return int(options.workers)
    return max(1, min(4, os.cpu_count() or 1))


def _planned_widths(g, seg, seg_move, filament_diameter) -> np.ndarray:
    """The width of every chord, by the one rule the layer targets are built with
    (:func:`printability.sources.gcode.segment_widths`): a round nozzle laying the
    planned width then fits G by construction."""
    from printability.sources.gcode import segment_widths

    width, _, _ = segment_widths(g, seg, seg_move, filament_diameter=filament_diameter,
                                 model="auto")
    return width


# ----------------------------------------------------------------- files


#: Peak memory of a run per byte of G-code, measured (peak RSS less the libraries' 0.2 GB):
#: the slicer's moves kept as they are (a round nozzle no larger than the slicer's), 22.6 for
#: a 200 MB, 8.5 M-line file; every move planned and turned (an elliptical nozzle), 90 on
#: 2-15 MB files: the plan, and the output (2.5 times as many lines) read again for its print
#: time.
BYTES_PER_BYTE_KEPT = 25
BYTES_PER_BYTE_PLANNED = 100


def _check_memory(size: int, path: object, *, binary: bool = False,
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


def _write_atomic(path: Path, content: bytes) -> None:
    """Write ``content`` to ``path`` through :func:`printability.base.files.replace_file`:
    the file keeps the mode and, where this process may set it, the owner of the one it
    replaces; a new file gets 0666 less the umask; a kill while writing leaves no
    temporary file beside it."""
    replace_file(path, content)


def postprocess_file(
    path: str | os.PathLike[str],
    *,
    options: PostprocessOptions = PostprocessOptions(),
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
    token = _PROGRESS.set(on_progress)
    try:
        return _postprocess_file(Path(path), options=options, output=output, env=env)
    finally:
        _PROGRESS.reset(token)


def _postprocess_file(p: Path, *, options: PostprocessOptions,
                      output: str | os.PathLike[str] | None,
                      env: Mapping[str, str] | None) -> PostprocessResult:
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
    _check_memory(st.st_size, p, planned=options.nozzle is not None
                  and not parse_nozzle(options.nozzle).is_round)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read the G-code file "
                                  f"({exc.strerror or exc})") from None
    environ = dict(os.environ) if env is None else dict(env)
    new, res = postprocess_bytes(data, path=str(p), options=options, env=environ)
    target = Path(output) if output is not None else p
    if res.already_processed and output is None:
        return res
    _progress(f"writing {target.name}")
    try:
        _write_atomic(target, new)
    except OSError as exc:
        raise PrintabilityOSError(f"{target}: cannot write the post-processed G-code "
                                  f"({exc.strerror or exc}); the original is unchanged") from None
    if options.output_name:
        try:
            _write_atomic(Path(str(p) + ".output_name"),
                          options.output_name.encode("utf-8") + b"\n")
        except OSError as exc:
            raise PrintabilityOSError(f"{p}.output_name: cannot write the output name "
                                      f"({exc.strerror or exc})") from None
    return PostprocessResult(**{**res.__dict__, "output": str(target)})
