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
tolerance, built as the union of one convex polygon per bead
(:mod:`printability.motion.beadunion`: between G ⊕ τ/2 and G ⊕ τ, without a
GEOS overlay). Non-part moves are left as they are.

A round nozzle no larger than the one the file was sliced for (the slicer's
``nozzle_diameter``) lays the slicer's own beads, each inside G by
construction: such a file only gets the comment block. A larger round nozzle,
or any other shape, is checked move by move with its whole orifice.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcode import NON_PART_CATEGORIES, parse_gcode
from gcode.rotary import nearest_equivalent
from gcode.writer import WriterOptions, format_number, header_lines
from printability import __version__
from printability.errors import FileFormatError, InputError, PrintabilityOSError
from printability.machine import Machine, parse_machine
from printability.motion.beadunion import INNER, bead_union
from printability.motion.orientation import (
    OrientationOptions,
    grown_target,
    plan_orientations,
)
from printability.nozzle import Nozzle, parse_nozzle
from printability.options import E_POLICIES, FEED_POLICIES

__all__ = [
    "LayerReport",
    "PostprocessOptions",
    "PostprocessResult",
    "already_processed",
    "postprocess_bytes",
    "postprocess_file",
    "settings_from_environment",
]

_PROCESSED = re.compile(rb"^; printability \S+ postprocessed this file", re.MULTILINE)


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
        release the GIL) while the planner runs; None: one per CPU core, at
        most 4.
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
        raise InputError(f"environment variable {key}={raw!r}: expected a number") from None
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
    """True when printability's marker comment is in the file."""
    return _PROCESSED.search(data) is not None


def _config_value(data: bytes, key: str) -> float | None:
    """A number from the slicer's configuration comments (``; key = value``)."""
    m = re.search(rb"^;\s*" + re.escape(key.encode()) + rb"\s*=\s*([-+0-9.eE]+)", data,
                  re.MULTILINE)
    if not m:
        return None
    try:
        return float(m.group(1))
    except ValueError:
        return None


# ----------------------------------------------------------------- layer targets


def _part_mask(g) -> np.ndarray:
    """Extrusions that belong to the part (not skirt, support, purge, wipe...)."""
    m = g.moves
    cats = g.feature_category_of_moves()
    part = np.array([c not in NON_PART_CATEGORIES for c in cats], dtype=bool)
    return m["is_extrusion"] & part & ~m["wipe"] & (m["layer"] >= 0)


# ----------------------------------------------------------------- the rewrite


@dataclass
class _Out:
    """Output chunks plus the bookkeeping of what changed."""

    chunks: list[bytes] = field(default_factory=list)
    changed: int = 0
    inserted: int = 0
    rotary_words: int = 0


def _eol_of(line: bytes) -> bytes:
    if line.endswith(b"\r\n"):
        return b"\r\n"
    if line.endswith((b"\n", b"\r")):
        return line[-1:]
    return b"\n"


def postprocess_bytes(
    data: bytes,
    *,
    path: str = "<bytes>",
    options: PostprocessOptions = PostprocessOptions(),
    env: Mapping[str, str] | None = None,
) -> tuple[bytes, PostprocessResult]:
    """Post-process G-code bytes; see the module docstring.

    Returns
    -------
    (bytes, PostprocessResult)
        The new content (the input itself when it was already processed).

    Raises
    ------
    FileFormatError, InputError
        Unreadable G-code, bad options.
    """
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
    policy = FEED_POLICIES.check(options.feed_policy or machine.feed_policy)
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

    g = parse_gcode(data, path=path)
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
    narrow_beads = bool(nozzle.is_round and (slicer_d is None
                                             or 2 * nozzle.footprints[0].a <= slicer_d + 1e-9))
    period = nozzle.symmetry_period
    turns = machine.kind == "ttr" and period != 0.0
    wopts = WriterOptions(letter=letter, period=period if turns else 0.0,
                          angle_min=machine.angle_min if machine.kind == "ttr" else 0.0,
                          angle_max=machine.angle_max if machine.kind == "ttr" else 0.0,
                          unwind=options.unwind, feed_policy=policy,
                          filament_diameter=float(fd), angle_decimals=options.angle_decimals)
    if machine.kind == "ttr" and machine.full_turn and not options.unwind:
        # a full-turn axis without cables turns freely: no limits on the coordinate
        wopts = WriterOptions(**{**wopts.__dict__, "angle_min": -math.inf,
                                 "angle_max": math.inf})

    part = _part_mask(g)
    part_idx = np.flatnonzero(part)
    seg = g.segments(moves=moves[part_idx]) if part_idx.size and not narrow_beads else \
        np.zeros(0, dtype=[("x0", "f8"), ("y0", "f8"), ("x1", "f8"), ("y1", "f8"),
                           ("e", "f8"), ("move", "i8")])
    # new lines are rounded to 4 decimals: keep that displacement inside the tolerance
    tol_grow = options.tolerance - wopts.rounding
    if part_idx.size and not narrow_beads:
        seg_move = part_idx[seg["move"]]  # index into g.moves
        widths = _planned_widths(g, seg, seg_move, float(fd))
        seg_layer = moves["layer"][seg_move]
        has_target, prepared = _layer_targets(g, float(fd), quad_segs, tol_grow,
                                              workers=_workers(options))
    else:
        seg_move = np.zeros(0, np.int64)
        widths = np.zeros(0)
        seg_layer = np.zeros(0, np.int64)
        has_target, prepared = [False] * n_layers, iter(())

    # ---- plan every layer
    seg_angle = np.zeros(len(seg))
    seg_fold = np.zeros(len(seg), dtype=bool)
    seg_width_laid = np.full(len(seg), np.nan)
    seg_pieces: dict[int, list] = {}
    reports: list[LayerReport] = []
    prev = 0.0
    order = np.argsort(seg_layer, kind="stable") if len(seg) else np.zeros(0, np.int64)
    bounds = np.searchsorted(seg_layer[order], np.arange(n_layers + 1)) if len(seg) else None
    seg_len = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"]) if len(seg) else np.zeros(0)
    for k in range(n_layers):
        if not has_target[k]:
            continue
        idx = order[bounds[k]:bounds[k + 1]]
        p0 = np.column_stack([seg["x0"][idx], seg["y0"][idx]])
        p1 = np.column_stack([seg["x1"][idx], seg["y1"][idx]])
        tgt, target_area = next(prepared)
        sm = seg_move[idx]
        chained = np.zeros(idx.size, dtype=bool)
        if idx.size > 1 and policy == "xy":
            same = (sm[1:] == sm[:-1]) | ((sm[1:] == sm[:-1] + 1)
                                          & (np.abs(p0[1:] - p1[:-1]).max(axis=1) < 1e-9))
            chained[1:] = same
        plan = plan_orientations(p0, p1, widths[idx], tgt, nozzle, machine,
                                 options=options.orientation, previous=prev,
                                 prepared_target=tgt, chained=chained,
                                 narrow_beads=narrow_beads)
        seg_angle[idx] = plan.angle
        seg_fold[idx] = plan.fold
        seg_width_laid[idx] = plan.width
        for i, pieces in plan.pieces.items():
            seg_pieces[int(idx[i])] = pieces
        finite = plan.angle[np.isfinite(plan.angle)]
        if finite.size:
            prev = float(finite[-1])
        dl = plan.dropped_length(seg_len[idx])
        dropped_area = 0.0
        for i, pieces in plan.pieces.items():
            kept = sum(p.t1 - p.t0 for p in pieces)
            dropped_area += float(seg_len[idx][i]) * max(0.0, 1 - kept) * float(widths[idx][i])
        reports.append(LayerReport(
            index=k, z=float(g.layers["z"][k]), target_area=target_area,
            moves=int(idx.size), turned=0, split_moves=plan.split_moves,
            dropped_moves=plan.dropped_moves, dropped_length=dl, dropped_area=dropped_area,
            printed_length=float(seg_len[idx].sum()) - dl,
        ))

    # ---- rewrite
    out, turned_per_layer = _rewrite(g, data, moves, seg, seg_move, seg_angle, seg_fold,
                                     seg_width_laid,
                                     seg_pieces, widths, heights, wopts, turns, e_policy,
                                     nozzle, options)
    reports = [LayerReport(**{**r.__dict__, "turned": turned_per_layer.get(r.index, 0)})
               for r in reports]
    summary = [{"z": r.z, "target_area": r.target_area, "lost_area": r.dropped_area,
                "dropped_moves": r.dropped_moves, "dropped_length": r.dropped_length,
                "split_moves": r.split_moves} for r in reports]
    notes = [
        "lost area = dropped length x planned width (what no orientation can print)",
        f"tolerance = {options.tolerance:g} mm; E policy = {e_policy}; layer targets from the "
        "slicer's part extrusions",
    ]
    if narrow_beads:
        notes.append("round nozzle no larger than the slicer's: it lays the slicer's own beads, "
                     "every move is kept as it is")
    head = header_lines(version=__version__, nozzle=nozzle.spec, machine=machine.spec,
                        options=wopts, mode="postprocessed", summary=summary, notes=notes)
    first_cmd = _first_command_line(lines)
    eol = _eol_of(g.line(first_cmd)) if len(lines) else b"\n"
    block = b"".join(h.encode("utf-8") + eol for h in head)
    body = out.chunks
    body.insert(first_cmd, block)
    result_bytes = b"".join(body)
    elapsed = time.perf_counter() - t_start
    res = PostprocessResult(
        path=path, output=path, already_processed=False, lines_in=len(lines),
        lines_out=len(lines) + out.inserted + len(head), changed_lines=out.changed,
        inserted_lines=out.inserted + len(head), rotary_words=out.rotary_words,
        layers=tuple(reports), elapsed=elapsed, nozzle=nozzle.spec, machine=machine.spec,
        notes=tuple(notes),
    )
    return result_bytes, res


def _workers(options: PostprocessOptions) -> int:
    if options.workers is not None:
        if options.workers < 1:
            raise InputError(f"workers must be at least 1; got {options.workers!r}")
        return int(options.workers)
    return max(1, min(4, os.cpu_count() or 1))


def _layer_targets(g, filament_diameter: float, quad_segs: int, tolerance: float, *,
                   workers: int = 1) -> tuple[list[bool], Iterator[tuple[object, float]]]:
    """Per layer, whether it has a target, and for those layers in order (the prepared
    target the planner tests footprints against, the area of G in mm²).

    G is the union of the layer's beads as :mod:`printability.sources.gcode` rebuilds it
    (the same reconstruction as ``printability analyze``, so the two agree on what the
    part is). The planner tests against G grown by ``tolerance``: the bead union of
    :mod:`printability.motion.beadunion`, built without an overlay, for which the area of
    G is the union's less ``tolerance``/2 × its perimeter (within that much of the exact
    area). A tolerance too small for that construction falls back to GEOS (the union,
    then a buffer), computed on ``workers`` threads while the caller plans.
    """
    from printability.settings import Settings
    from printability.sources.gcode import layer_beads, layer_regions

    settings = Settings(quad_segs=quad_segs, workers=workers)
    seg, width, _, _, bounds, _ = layer_beads(g, settings=settings,
                                              filament_diameter=filament_diameter)
    good = np.isfinite(width) & (width > 0)
    per_layer = [np.flatnonzero(good[bounds[k]:bounds[k + 1]]) + bounds[k]
                 for k in range(len(g.layers))]
    has = [rows.size > 0 for rows in per_layer]
    r_max = float(width[good].max()) / 2 if good.any() else 0.0
    if _union_edges(r_max, tolerance) <= 256:
        def one(rows: np.ndarray) -> tuple[object, float]:
            s = seg[rows]
            u = bead_union(np.column_stack([s["x0"], s["y0"]]),
                           np.column_stack([s["x1"], s["y1"]]), width[rows] / 2,
                           grow=tolerance)
            return u, max(0.0, u.area - tolerance / 2 * u.perimeter)

        todo = [rows for rows in per_layer if rows.size]
        if workers <= 1:
            return has, map(one, todo)
        return has, _threaded(one, todo, workers)

    # GEOS: G, then G grown by the tolerance
    regions = [None] * len(g.layers)
    for li, geom, _facts in layer_regions(g, settings=settings,
                                          filament_diameter=filament_diameter):
        regions[li] = geom if geom is not None and not geom.is_empty else None
    has = [r is not None for r in regions]
    todo = [r for r in regions if r is not None]

    def grown(t) -> tuple[object, float]:
        return grown_target(t, tolerance), float(t.area)

    if workers <= 1:
        return has, map(grown, todo)
    return has, _threaded(grown, todo, workers)


def _union_edges(r: float, tolerance: float) -> float:
    """Edges per half turn of the widest bead's polygon in the bead union (inf: the
    tolerance is too small for it)."""
    rho, rmax = r + tolerance / 2, r * INNER + tolerance
    if not (tolerance > 0 and rho < rmax):
        return math.inf
    return math.ceil(math.pi / (2 * math.acos(rho / rmax)))


def _threaded(fn, items: list, workers: int):
    """``map(fn, items)`` on ``workers`` threads, running ahead of the consumer (the
    kernels release the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(workers) as ex:
        yield from ex.map(fn, items)


def _planned_widths(g, seg, seg_move, filament_diameter) -> np.ndarray:
    """The width of every chord, by the one rule the layer targets are built with
    (:func:`printability.sources.gcode.segment_widths`): a round nozzle laying the
    planned width then fits G by construction."""
    from printability.sources.gcode import segment_widths

    width, _, _ = segment_widths(g, seg, seg_move, filament_diameter=filament_diameter,
                                 model="auto")
    return width


@dataclass(frozen=True)
class _ZRamp:
    """Z along a climbing move's chords (spiral vase), by path length."""

    z0: float
    z1: float
    first: int  # index of the move's first chord
    length: list[float]
    start: list[float]  # path length before each chord; the last item is the total
    decimals: int

    def word(self, s: int, t: float) -> bytes:
        """`` Z…`` at fraction ``t`` of chord ``s``."""
        total = self.start[-1] if self.start[-1] > 0 else 1.0
        k = s - self.first
        z = self.z0 + (self.z1 - self.z0) * min(1.0, (self.start[k] + t * self.length[k]) / total)
        return b" Z" + format_number(z, self.decimals).encode()


def _no_z_word(s: int, t: float) -> bytes:
    return b""


def _first_command_line(lines: np.ndarray) -> int:
    from gcode._lexer import KIND_BLANK, KIND_COMMENT

    idx = np.flatnonzero((lines["kind"] != KIND_COMMENT) & (lines["kind"] != KIND_BLANK))
    return int(idx[0]) if idx.size else len(lines)


def _rewrite(g, data, moves, seg, seg_move, seg_angle, seg_fold, seg_width_laid, seg_pieces,
             widths,
             heights, wopts: WriterOptions, turns: bool, e_policy: str, nozzle: Nozzle,
             options: PostprocessOptions):
    """Copy the file, rewriting the part extrusions that need it.

    Only the lines of moves that may change are looked at one by one; the runs of
    lines between them are copied as single slices of ``data``. The chunks of the
    result are one per line up to the first command line (the header goes there),
    then runs and rewritten lines.
    """
    from gcode.line import parse_line
    from gcode.rotary import bead_area
    from gcode.writer import edit_line, simple_move_words

    out = _Out()
    n_lines = len(g.lines)
    starts = [*g.lines["start"].tolist(), len(data)]
    n_moves = len(moves)
    # chords of each move (a later run of chords of the same move wins, as in a dict)
    first_seg: dict[int, tuple[int, int]] = {}
    has_seg = np.zeros(n_moves, dtype=bool)
    with_pieces = np.zeros(n_moves, dtype=bool)
    if len(seg):
        change = np.flatnonzero(np.diff(seg_move)) + 1
        b = np.concatenate([[0], change, [len(seg_move)]])
        first_seg = dict(zip(seg_move[b[:-1]].tolist(),
                             zip(b[:-1].tolist(), b[1:].tolist(), strict=True), strict=True))
        keys = np.fromiter(first_seg, dtype=np.int64, count=len(first_seg))
        ranges = np.array(list(first_seg.values()), dtype=np.int64).reshape(-1, 2)
        has_seg[keys] = True
        piece_flag = np.zeros(len(seg) + 1, dtype=np.int64)
        if seg_pieces:
            piece_flag[np.fromiter(seg_pieces, dtype=np.int64, count=len(seg_pieces)) + 1] = 1
        csum = np.cumsum(piece_flag)
        with_pieces[keys] = csum[ranges[:, 1]] > csum[ranges[:, 0]]

    # the move of each line: the last move listed on it
    mv_line = moves["line"].astype(np.int64)
    lines_u, last_rev = np.unique(mv_line[::-1], return_index=True)
    move_u = n_moves - 1 - last_rev
    keep = (lines_u >= 0) & (lines_u < n_lines)
    lines_u, move_u = lines_u[keep], move_u[keep]

    fold = wopts.feed_policy == "xy"
    # what each move line does to the travel a turn may be folded into (see below)
    _NONE, _TRAVEL, _RESET, _WORK = 0, 1, 2, 3
    work = has_seg & (with_pieces | turns)
    with np.errstate(invalid="ignore"):
        is_travel = ((moves["e"] <= 0) & (moves["kind"] <= 1)
                     & ((moves["x1"] != moves["x0"]) | (moves["y1"] != moves["y0"])))
        extruding = moves["e"] > 0
    effect = np.full(n_moves, _NONE, dtype=np.int8)
    effect[extruding] = _RESET
    if turns:
        effect[has_seg] = _RESET
        if fold:
            effect[is_travel] = _TRAVEL
    effect[work] = _WORK
    ev = effect[move_u] != _NONE
    ev_line = lines_u[ev].tolist()
    ev_move = move_u[ev].tolist()
    ev_code = effect[move_u[ev]].tolist()

    # per-move and per-chord columns as Python objects: the loop below reads them one by one
    m_e = moves["e"].tolist()
    m_kind = moves["kind"].tolist()
    m_flags = moves["flags"].tolist()
    m_layer = moves["layer"].tolist()
    m_x0, m_y0 = moves["x0"].tolist(), moves["y0"].tolist()
    m_x1, m_y1 = moves["x1"].tolist(), moves["y1"].tolist()
    m_z0, m_z1 = moves["z0"].tolist(), moves["z1"].tolist()
    s_x0, s_y0 = seg["x0"].tolist(), seg["y0"].tolist()
    s_x1, s_y1 = seg["x1"].tolist(), seg["y1"].tolist()
    s_e = seg["e"].tolist()
    s_angle = np.asarray(seg_angle, dtype=float).tolist()
    s_fold = np.asarray(seg_fold, dtype=bool).tolist()
    s_turn = _planned_turns(np.asarray(seg_angle, dtype=float)).tolist()
    heights_l = np.asarray(heights, dtype=float).tolist()
    if len(seg):
        layer_of_seg = moves["layer"][seg_move]
        h_seg = np.where(layer_of_seg >= 0,
                         np.asarray(heights, dtype=float)[np.maximum(layer_of_seg, 0)]
                         if len(heights) else 0.2, 0.2)
        s_scale = _e_scales(np.asarray(seg_width_laid, dtype=float),
                            np.asarray(widths, dtype=float), h_seg, e_policy, nozzle,
                            bead_area).tolist()
    else:
        s_scale = []

    cur = 0.0  # rotary coordinate
    letter = wopts.letter
    d_ang = wopts.angle_decimals
    cur_text = format_number(cur, d_ang)
    last_travel_chunk: int | None = None  # chunk index of a travel we may fold C into
    xd = wopts.xy_decimals
    ed = 5
    turned: dict[int, int] = {}
    period = wopts.period or 360.0
    lo, hi = wopts.angle_min, wopts.angle_max
    chunks = out.chunks

    unbounded = math.isinf(lo) and math.isinf(hi) and lo < 0 < hi

    def coord_for(phi: float, *, unwind: bool = False) -> float:
        prev = 0.0 if unwind else cur
        if unbounded:
            # nearest_equivalent without limits, inlined (the same operations, so the
            # same bits): it runs once per rewritten move
            k = round((prev - phi) / period)
            best = phi + (k - 1) * period
            bd = abs(best - prev)
            cand = phi + k * period
            if abs(cand - prev) < bd - 1e-12:
                best, bd = cand, abs(cand - prev)
            cand = phi + (k + 1) * period
            if abs(cand - prev) < bd - 1e-12:
                best = cand
            return best
        c = nearest_equivalent(phi, prev, period=period, lo=lo, hi=hi)
        if c is None:  # cannot happen: candidates were filtered to reachable ones
            raise InputError(f"orientation {phi:.3f}° is outside the rotary axis limits")
        return c

    angle_texts: dict[float, str] = {}

    def angle_text(c: float) -> str:
        # rotary coordinates repeat along straight runs and curves: format each once
        t = angle_texts.get(c)
        if t is None:
            t = angle_texts[c] = format_number(c, d_ang)
        return t

    def turn_to(phi: float, c: float, c_text: str, eol: bytes, layer: int) -> None:
        # a turn before the move: folded into the travel before it, else a move of its own
        nonlocal cur, cur_text, last_travel_chunk
        if c_text == cur_text:
            return
        word = letter + c_text
        if fold and last_travel_chunk is not None:
            if wopts.unwind:
                c = coord_for(phi, unwind=True)
                c_text = format_number(c, d_ang)
                word = letter + c_text
            chunks[last_travel_chunk] = edit_line(chunks[last_travel_chunk], add=[word])
        else:
            chunks.append(b"G1 " + word.encode() + eol)
            out.inserted += 1
        out.rotary_words += 1
        turned[layer] = turned.get(layer, 0) + 1
        cur = c
        cur_text = c_text
        last_travel_chunk = None

    def words(raw: bytes, e_rel: bool, e_move: float):
        # read only where a word is needed: most moves only gain a rotary word
        ws = simple_move_words(raw)
        if ws is not None:
            f_text = e_text = None
            for w in ws:
                if f_text is None and w[:1] == b"F":
                    f_text = w.decode("ascii")
                elif e_text is None and w[:1] == b"E":
                    e_text = w
            has_e = e_text is not None
            e_value = float(e_text[1:]) if has_e else None
        else:
            parsed = parse_line(raw)
            fword = parsed.word("F")
            f_text = fword.text.decode("ascii", "replace") if fword is not None else None
            eword = parsed.word("E")
            has_e = eword is not None
            e_value = eword.value if has_e else None
        e_end_abs = e_value if (has_e and not e_rel) else None
        e_start_abs = (e_end_abs - e_move) if e_end_abs is not None else None
        return f_text, has_e, e_end_abs, e_start_abs

    # the lines before the first command are chunks of their own: the header goes among them
    first_cmd = min(_first_command_line(g.lines), ev_line[0] if ev_line else n_lines)
    for li in range(first_cmd):
        chunks.append(data[starts[li]:starts[li + 1]])
    pos = starts[first_cmd]  # data before pos is in the chunks
    pending: int | None = None  # the last travel line since the last rewritten move

    for li, mi, code in zip(ev_line, ev_move, ev_code, strict=True):
        # A turn may be folded into the last travel before the move when no extrusion
        # came in between; every rewritten move ends that chance.
        if code == _TRAVEL:
            pending = li
            continue
        if code == _RESET:
            pending = None
            continue
        if pending is not None:
            chunks.append(data[pos:starts[pending]])
            chunks.append(data[starts[pending]:starts[pending + 1]])
            last_travel_chunk = len(chunks) - 1
            pos = starts[pending + 1]
            pending = None
        else:
            last_travel_chunk = None
        chunks.append(data[pos:starts[li]])
        pos = starts[li + 1]
        raw = data[starts[li]:pos]

        # ---- this move is rewritten
        layer = m_layer[mi]
        a0, a1 = first_seg[mi]
        eol = _eol_of(raw)
        e_rel = bool(m_flags[mi] & 1)
        e_move = m_e[mi]
        simple = (a1 - a0 == 1 and a0 not in seg_pieces and m_kind[mi] <= 1)
        h = heights_l[layer] if layer >= 0 else 0.2
        if simple:
            phi = s_angle[a0]
            add: list[str] = []
            if turns and math.isfinite(phi):
                c = coord_for(phi)
                c_text = angle_text(c)
                if s_fold[a0] and abs(c - cur) <= s_turn[a0] + 1e-6:
                    # the turn checked by the planner, made while moving
                    if c_text != cur_text:
                        add = [letter + c_text]
                        out.rotary_words += 1
                        turned[layer] = turned.get(layer, 0) + 1
                        cur = c
                        cur_text = c_text
                else:
                    turn_to(phi, c, c_text, eol, layer)
            scale = s_scale[a0]
            replace = {}
            if scale != 1.0:
                _, has_e, e_end_abs, e_start_abs = words(raw, e_rel, e_move)
                if has_e:
                    if e_rel:
                        replace = {"E": "E" + format_number(e_move * scale, ed)}
                    else:
                        replace = {"E": "E" + format_number(e_start_abs + e_move * scale, ed)}
            if replace or add:
                chunks.append(edit_line(raw, replace=replace, add=add))
                out.changed += 1
                if replace and not e_rel:
                    chunks.append(f"G92 E{format_number(e_end_abs, ed)}".encode() + eol)
                    out.inserted += 1
            else:
                chunks.append(raw)
            last_travel_chunk = None
            continue
        # ---- general case: chords and pieces, written as new G1 lines
        f_text, _, e_end_abs, e_start_abs = words(raw, e_rel, e_move)
        out.changed += 1
        e_acc = 0.0
        first = True
        px, py = m_x0[mi], m_y0[mi]
        comment = b" ; printability: was " + raw.rstrip(b"\r\n").strip()[:60]
        lines_new: list[bytes] = []
        # A move that also climbs (spiral vase) climbs along its new lines too, by path
        # length, instead of stepping Z at the end.
        z0, z1 = m_z0[mi], m_z1[mi]
        ramp = None
        if z1 != z0 and math.isfinite(z0) and math.isfinite(z1):
            c_len = [math.hypot(s_x1[s] - s_x0[s], s_y1[s] - s_y0[s]) for s in range(a0, a1)]
            ramp = _ZRamp(z0, z1, a0, c_len, list(itertools.accumulate(c_len, initial=0.0)),
                          xd)
        z_word = ramp.word if ramp is not None else _no_z_word
        for s in range(a0, a1):
            sx0, sy0, sx1, sy1 = s_x0[s], s_y0[s], s_x1[s], s_y1[s]
            se = s_e[s]
            in_pieces = s in seg_pieces
            if in_pieces:
                plist = [(p.t0, p.t1, p.angle) for p in seg_pieces[s]]
            else:
                plist = [(0.0, 1.0, s_angle[s])]
            for t0, t1, phi in plist:
                qx0, qy0 = sx0 + t0 * (sx1 - sx0), sy0 + t0 * (sy1 - sy0)
                qx1, qy1 = sx0 + t1 * (sx1 - sx0), sy0 + t1 * (sy1 - sy0)
                if math.hypot(qx0 - px, qy0 - py) > 1e-9:
                    lines_new.append(b"G1 X" + format_number(qx0, xd).encode() + b" Y"
                                     + format_number(qy0, xd).encode() + z_word(s, t0))
                    px, py = qx0, qy0
                c_word = b""
                if turns and math.isfinite(phi):
                    c = coord_for(phi)
                    c_text = angle_text(c)
                    if c_text != cur_text:
                        c_word = (letter + c_text).encode()
                        if not (s_fold[s] and not in_pieces
                                and abs(c - cur) <= s_turn[s] + 1e-6):
                            lines_new.append(b"G1 " + c_word)
                            c_word = b""
                        out.rotary_words += 1
                        turned[layer] = turned.get(layer, 0) + 1
                        cur = c
                        cur_text = c_text
                if in_pieces:
                    scale = 1.0
                    if math.isfinite(phi):
                        rel = math.degrees(math.atan2(sy1 - sy0, sx1 - sx0))
                        w_laid = nozzle.bead_width(rel, phi) if turns else float("nan")
                        scale = _e_scale(w_laid, widths[s], h, e_policy, nozzle, bead_area)
                else:
                    scale = s_scale[s]
                de = se * (t1 - t0) * scale
                e_acc += de
                if e_rel:
                    e_word = b"E" + format_number(de, ed).encode()
                else:
                    e_word = b"E" + format_number(e_start_abs + e_acc, ed).encode()
                ws = [b"G1", b"X" + format_number(qx1, xd).encode(),
                      b"Y" + format_number(qy1, xd).encode() + z_word(s, t1), e_word]
                if c_word:
                    ws.append(c_word)
                if first and f_text is not None:
                    ws.append(f_text.encode())
                first = False
                lines_new.append(b" ".join(ws))
                px, py = qx1, qy1
        ex, ey = m_x1[mi], m_y1[mi]
        if math.hypot(ex - px, ey - py) > 1e-9 or not lines_new:
            ws = [b"G1", b"X" + format_number(ex, xd).encode(),
                  b"Y" + format_number(ey, xd).encode() + z_word(a1 - 1, 1.0)]
            if first and f_text is not None:
                ws.append(f_text.encode())
            lines_new.append(b" ".join(ws))
        if z1 != z0 and math.isfinite(z1) and ramp is None:
            lines_new.append(b"G1 Z" + format_number(z1, xd).encode())
        if not e_rel and e_end_abs is not None and abs(e_acc - e_move) > 10 ** -ed:
            lines_new.append(b"G92 E" + format_number(e_end_abs, ed).encode())
        lines_new[0] = lines_new[0] + comment
        chunks.extend(ln + eol for ln in lines_new)
        out.inserted += len(lines_new) - 1
        last_travel_chunk = None
    chunks.append(data[pos:])
    return out, turned


def _planned_turns(seg_angle: np.ndarray) -> np.ndarray:
    """Per chord, the turn into it the planner checked (from the chord before), degrees.

    A turn folded into an extruding move must be that one: near an axis limit the
    coordinate may have to go the long way round, which was never checked. -1 where
    there is none (first chord, or an orientation that is not finite).
    """
    out = np.full(len(seg_angle), -1.0)
    if len(seg_angle) > 1:
        a, b = seg_angle[1:], seg_angle[:-1]
        ok = np.isfinite(a) & np.isfinite(b)
        out[1:][ok] = np.abs(a[ok] - b[ok])
    return out


def _e_scales(w_laid: np.ndarray, w_plan: np.ndarray, h: np.ndarray, e_policy: str,
              nozzle: Nozzle, bead_area) -> np.ndarray:
    """:func:`_e_scale` of every chord at once (the same operations, so the same bits)."""
    scale = np.ones(len(w_laid))
    if e_policy != "width" or nozzle.is_round:
        return scale
    with np.errstate(invalid="ignore", divide="ignore"):
        a_plan = bead_area(w_plan, h)
        a_laid = bead_area(w_laid, h)
        ok = (np.isfinite(w_laid) & np.isfinite(w_plan)
              & ~(np.abs(w_laid - w_plan) <= 0.01 * w_plan) & (a_plan > 0))
    scale[ok] = a_laid[ok] / a_plan[ok]
    return scale


def _e_scale(w_laid: float, w_plan: float, h: float, e_policy: str, nozzle: Nozzle,
             bead_area) -> float:
    """Factor applied to the slicer's E for a bead laid ``w_laid`` wide instead of ``w_plan``."""
    if e_policy != "width" or nozzle.is_round or not (math.isfinite(w_laid)
                                                       and math.isfinite(w_plan)):
        return 1.0
    if abs(w_laid - w_plan) <= 0.01 * w_plan:
        return 1.0
    a_plan = float(bead_area(w_plan, h))
    return float(bead_area(w_laid, h)) / a_plan if a_plan > 0 else 1.0


# ----------------------------------------------------------------- files


def _write_atomic(path: Path, content: bytes) -> None:
    """Write ``content`` to ``path`` through a temporary file in the same directory."""
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(content)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            mode = path.stat().st_mode & 0o7777
            os.chmod(tmp, mode)
        except OSError:
            pass
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def postprocess_file(
    path: str | os.PathLike[str],
    *,
    options: PostprocessOptions = PostprocessOptions(),
    output: str | os.PathLike[str] | None = None,
    env: Mapping[str, str] | None = None,
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

    Raises
    ------
    PrintabilityOSError, FileFormatError, InputError
    """
    p = Path(path)
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
