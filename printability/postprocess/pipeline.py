"""The post-processing pipeline: :func:`postprocess_bytes` and its stages, in the order they
run (the package's docstring says what each change means to the print).

1. :func:`choose_nozzle`, :func:`parse_slicer_gcode`, :func:`settle_job`: the machine, the
   nozzle and the file read and checked; what the run is for settled in a :class:`Job`;
2. :func:`part_chords`: the part's extrusions as chords (:class:`Chords`);
3. :func:`layer_target_batches`: the layer targets, built in batches on threads;
4. :func:`plan_layers`: the orientation of every chord (:class:`LayerPlans`);
5. :func:`rewrite_moves`: the slicer's file copied with the moves that need it rewritten;
6. :func:`run_notes`, :func:`estimate_print_times`: what the run says of itself, and the
   print time before and after;
7. :func:`header_lines_of`, :func:`with_header`: the comment block put before the first
   command;
8. :func:`check_something_printed`, :func:`run_result`: the outcome.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from gcode import MF_E_RELATIVE, NON_PART_CATEGORIES, parse_gcode
from gcode.bgcode import is_bgcode
from gcode.dialects import INTERIOR_CATEGORIES
from gcode.flavors import Flavor, RotaryAxis
from gcode.printtime import PrintTime, estimate_print_time
from gcode.writer import WriterOptions, format_number, header_lines
from printability import __version__
from printability.base.arrays import take_rows
from printability.errors import FileFormatError, InputError, NozzleTooLargeError
from printability.model.machine import Machine, parse_machine
from printability.model.nozzle import Nozzle, parse_nozzle
from printability.options import E_POLICIES, FEED_POLICIES
from printability.planning.orientation import PieceMap, Plan, plan_orientations
from printability.planning.targets import layer_targets
from printability.postprocess.binary import postprocess_binary
from printability.postprocess.memory import check_memory
from printability.postprocess.options import (
    DEFAULT_OPTIONS,
    PostprocessOptions,
    settings_from_environment,
    worker_count,
)
from printability.postprocess.progress import counted, progress
from printability.postprocess.results import (
    LayerReport,
    PostprocessResult,
    filament,
    layer_reports,
    layer_summary,
    print_time_note,
    unchanged_result,
)
from printability.postprocess.rewrite import (
    ChordPlan,
    RewriteOutput,
    SlicerFile,
    WriteSettings,
    eol_of,
    first_command_line,
    rewrite,
)
from printability.postprocess.scan import already_processed, config_value

if TYPE_CHECKING:  # pragma: no cover
    from gcode.reader import GCodeFile

#: Segments per quarter circle of the layer targets' round caps
QUAD_SEGS = 32

_CHORD_DTYPE = [("x0", "f8"), ("y0", "f8"), ("x1", "f8"), ("y1", "f8"), ("e", "f8"),
                ("move", "i8")]


def postprocess_bytes(
    data: bytes,
    *,
    path: str = "<bytes>",
    options: PostprocessOptions = DEFAULT_OPTIONS,
    env: Mapping[str, str] | None = None,
) -> tuple[bytes, PostprocessResult]:
    """Post-process G-code bytes; see the package docstring.

    Binary G-code (``.bgcode``, recognised by its content) comes back as binary G-code:
    see :func:`~printability.postprocess.binary.postprocess_binary`.

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
        return postprocess_binary(data, postprocess_bytes, path=path, options=options, env=env)
    t_start = time.perf_counter()
    envs = settings_from_environment(env if env is not None else {})
    if already_processed(data):
        return data, unchanged_result(path, data.count(b"\n"))
    machine = parse_machine(options.machine)
    nozzle = choose_nozzle(data, path, options=options, envs=envs)
    g = parse_slicer_gcode(data, path)
    job = settle_job(data, path, g, machine, nozzle, options=options, envs=envs)
    chords = part_chords(g, job)
    batches = layer_target_batches(g, chords, job, options=options)
    plans = plan_layers(g, chords, batches, job, options=options)
    out, turned = rewrite_moves(g, data, chords, plans, job, options=options)
    reports = [replace(r, turned=turned.get(r.index, 0)) for r in plans.reports]
    axis = rotary_axis(job)
    notes = run_notes(job, axis, options=options)
    estimates = estimate_print_times(g, out, path, job.machine, axis)
    notes.append(print_time_note(estimates.before.total, estimates.after))
    head = header_lines_of(g, job, axis, reports, notes)
    new = with_header(g, out, head)
    check_something_printed(reports, path, job, options=options)
    return new, run_result(path, g, out, job, n_header=len(head), reports=reports, notes=notes,
                           estimates=estimates, t_start=t_start)


# ----------------------------------------------------------------- the input


@dataclass(frozen=True)
class Job:
    """What a run is for, settled from the options, the slicer's environment and the file
    before anything is planned."""

    machine: Machine
    nozzle: Nozzle
    #: the machine's firmware, else the one the slicer wrote the file for
    flavor: Flavor
    feed_policy: str
    e_policy: str
    #: the rotary axis's letter (upper case)
    letter: str
    filament_diameter: float
    #: per layer of the file, mm (the slicer's, else the options' or the environment's)
    heights: np.ndarray
    #: a round nozzle no larger than the slicer's: it lays the slicer's own beads
    narrow_beads: bool
    #: the nozzle turns on this machine (rotary words are written)
    turns: bool
    writer: WriterOptions
    workers: int


def choose_nozzle(data: bytes, path: str, *, options: PostprocessOptions,
                  envs: Mapping[str, object]) -> Nozzle:
    """The options' nozzle, else a round one of the slicer's ``nozzle_diameter``."""
    if options.nozzle is not None:
        return parse_nozzle(options.nozzle)
    d = envs.get("nozzle_diameter") or config_value(data, "nozzle_diameter")
    if d is None:
        raise InputError(f"{path}: no nozzle given: pass --nozzle SPEC (e.g. "
                         "ellipse:major=0.8,minor=0.3); the slicer's nozzle_diameter was not "
                         "found either")
    return parse_nozzle(f"circle:d={format_number(float(d), 4)}")


def parse_slicer_gcode(data: bytes, path: str) -> GCodeFile:
    """The slicer's file, parsed."""
    progress("reading the G-code")
    return parse_gcode(data, path=path)


def settle_job(data: bytes, path: str, g: GCodeFile, machine: Machine, nozzle: Nozzle, *,
               options: PostprocessOptions, envs: Mapping[str, object]) -> Job:
    """What the run is for (see :class:`Job`); refuses what post-processing cannot do (feed
    policy ``inverse-time``, inches) and a file that would need more memory than allowed."""
    flavor = machine.firmware(g.flavor)
    policy = _feed_policy(path, machine, flavor, options=options)
    e_policy = E_POLICIES.check(options.e_policy)
    letter = (options.letter or machine.rotary_letter).upper()
    fd = float(options.filament_diameter or envs.get("filament_diameter")
               or config_value(data, "filament_diameter") or machine.filament_diameter)
    heights = _layer_heights(g, options=options, envs=envs)
    _check_millimetres(g.moves, path)
    narrow_beads = _lays_slicer_beads(data, g.moves, nozzle, heights, fd, envs)
    if not narrow_beads:
        check_memory(len(data), path, planned=True)  # before the plan grows
    turns = machine.turns(nozzle)
    writer = _writer_options(machine, nozzle, turns, options=options, letter=letter,
                             feed_policy=policy, filament_diameter=fd)
    return Job(machine=machine, nozzle=nozzle, flavor=flavor, feed_policy=policy,
               e_policy=e_policy, letter=letter, filament_diameter=fd, heights=heights,
               narrow_beads=narrow_beads, turns=turns, writer=writer,
               workers=worker_count(options))


def _feed_policy(path: str, machine: Machine, flavor: Flavor, *,
                 options: PostprocessOptions) -> str:
    policy = FEED_POLICIES.check(options.feed_policy or machine.feed_policy_for(flavor))
    if policy == "inverse-time":
        raise InputError(
            f"{path}: feed policy inverse-time (G93) needs an F word on every move, so every "
            "line of the slicer's file would change; post-processing keeps the slicer's lines. "
            "Use feed policy xy or euclidean, or 'printability generate'"
        )
    return policy


def _layer_heights(g: GCodeFile, *, options: PostprocessOptions,
                   envs: Mapping[str, object]) -> np.ndarray:
    """The height of every layer: the options', else the file's, else the environment's,
    else 0.2 mm."""
    heights = g.layers["height"].copy() if len(g.layers) else np.zeros(0)
    if options.layer_height is not None:
        heights[:] = options.layer_height
    return np.where(np.isfinite(heights) & (heights > 0), heights,
                    envs.get("layer_height") or 0.2)


def _check_millimetres(moves: np.ndarray, path: str) -> None:
    if moves.size and (moves["flags"] & 4).any():
        raise FileFormatError(path, "the file uses inches (G20); only millimetre G-code is "
                              "supported", line=int(moves["line"][(moves["flags"] & 4) > 0][0]) + 1)


def _lays_slicer_beads(data: bytes, moves: np.ndarray, nozzle: Nozzle, heights: np.ndarray,
                       filament_diameter: float, envs: Mapping[str, object]) -> bool:
    """A round nozzle no larger than the one the file was sliced for lays the slicer's own
    beads: each is inside G by construction (G is their union), so nothing moves."""
    slicer_d = envs.get("nozzle_diameter") or config_value(data, "nozzle_diameter")
    if slicer_d is None:
        slicer_d = _typical_bead_width(moves, heights, filament_diameter)
    return bool(nozzle.is_round and 2 * nozzle.footprints[0].a <= slicer_d + 1e-9)


def _typical_bead_width(moves: np.ndarray, heights: np.ndarray,
                        filament_diameter: float) -> float:
    """The nozzle a file that does not say (Cura's, or a settings block cut off) was sliced
    for: the beads it plans are about its nozzle's width (Cura's lines are the nozzle's size,
    PrusaSlicer's 1.05-1.1x)."""
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
        planned = width_from_e(mm["e"][ok] / length[ok], h[ok], filament_diameter)
    return float(np.median(planned)) if planned.size else 0.0


def _writer_options(machine: Machine, nozzle: Nozzle, turns: bool, *,
                    options: PostprocessOptions, letter: str, feed_policy: str,
                    filament_diameter: float) -> WriterOptions:
    period = nozzle.symmetry_period
    wopts = WriterOptions(letter=letter, period=period if turns else 0.0,
                          angle_min=machine.angle_min if machine.has_rotary else 0.0,
                          angle_max=machine.angle_max if machine.has_rotary else 0.0,
                          unwind=options.unwind, feed_policy=feed_policy,
                          rotary_feed=machine.rotary_axis.rotation_feed,
                          filament_diameter=filament_diameter,
                          angle_decimals=options.angle_decimals)
    if machine.full_turn and not options.unwind:
        # a full-turn axis without cables turns freely: no limits on the coordinate
        wopts = WriterOptions(**{**wopts.__dict__, "angle_min": -math.inf,
                                 "angle_max": math.inf})
    return wopts


# ----------------------------------------------------------------- chords and targets


@dataclass(frozen=True)
class Chords:
    """The part's extrusions as chords (arcs linearised), with what planning needs of each."""

    #: x0, y0, x1, y1, e and the row of the move in the part's moves
    seg: np.ndarray
    length: np.ndarray
    #: the move of each chord: index into ``g.moves``
    move: np.ndarray
    #: the slicer's planned width
    width: np.ndarray
    #: True where the feature's bead edges are not the part's surface
    interior: np.ndarray
    #: the chords by layer, and each layer's rows of ``order`` (one entry per layer and one
    #: more)
    order: np.ndarray
    bounds: np.ndarray
    #: the part's moves are planned: there are some, and the nozzle does not lay the
    #: slicer's own beads
    planned: bool


def part_chords(g: GCodeFile, job: Job) -> Chords:
    """The chords of the part's extrusions (none when nothing is planned)."""
    moves = g.moves
    n_layers = len(g.layers)
    part_idx = np.flatnonzero(_part_mask(g))
    if not part_idx.size or job.narrow_beads:
        return Chords(seg=np.zeros(0, dtype=_CHORD_DTYPE), length=np.zeros(0),
                      move=np.zeros(0, np.int64), width=np.zeros(0),
                      interior=np.zeros(0, dtype=bool), order=np.zeros(0, np.int64),
                      bounds=np.zeros(n_layers + 1, np.int64), planned=False)
    seg = g.segments(moves=take_rows(moves, part_idx))
    length = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"]) if len(seg) \
        else np.zeros(0)
    seg_move = part_idx[seg["move"]]  # index into g.moves
    seg_layer = moves["layer"][seg_move]
    order = np.argsort(seg_layer, kind="stable")
    return Chords(seg=seg, length=length, move=seg_move,
                  width=_planned_widths(g, seg, seg_move, job.filament_diameter),
                  interior=g.moves_in(INTERIOR_CATEGORIES)[seg_move], order=order,
                  bounds=np.searchsorted(seg_layer[order], np.arange(n_layers + 1)),
                  planned=True)


def _part_mask(g: GCodeFile) -> np.ndarray:
    """Extrusions that belong to the part (not skirt, support, purge, wipe...)."""
    m = g.moves
    return m["is_extrusion"] & ~g.moves_in(NON_PART_CATEGORIES) & ~m["wipe"] & (m["layer"] >= 0)


def _planned_widths(g: GCodeFile, seg: np.ndarray, seg_move: np.ndarray,
                    filament_diameter: float) -> np.ndarray:
    """The width of every chord, by the one rule the layer targets are built with
    (:func:`printability.sources.gcode.segment_widths`): a round nozzle laying the
    planned width then fits G by construction."""
    from printability.sources.gcode import segment_widths

    width, _, _ = segment_widths(g, seg, seg_move, filament_diameter=filament_diameter,
                                 model="auto")
    return width


def layer_target_batches(g: GCodeFile, chords: Chords, job: Job, *,
                         options: PostprocessOptions) -> Iterator[tuple]:
    """The batches of :func:`printability.planning.targets.layer_targets` (built on threads while
    the caller plans), each reported as planned when the next is asked for."""
    if not chords.planned:
        return iter(())
    # new lines are rounded to 4 decimals: keep that displacement inside the tolerance
    tol_grow = options.tolerance - job.writer.rounding
    batches = layer_targets(g, job.filament_diameter, QUAD_SEGS, tol_grow, workers=job.workers,
                            planned=(chords.seg, chords.order, chords.bounds),
                            reach=job.nozzle.radius, interior=options.interior)
    return counted(batches, len(g.layers))


# ----------------------------------------------------------------- planning


@dataclass(frozen=True)
class LayerPlans:
    """The orientation of every chord, and what it did to each layer."""

    angle: np.ndarray
    #: True where the turn into the chord is made during the travel before it
    fold: np.ndarray
    #: the width laid at that orientation (NaN where none was planned)
    width_laid: np.ndarray
    #: the split chords' pieces (:class:`~printability.planning.orientation.PieceMap`)
    pieces: Mapping[int, list]
    #: the pieces as arrays ``(chord, t0, t1, angle)`` by chord, and their folds; None when
    #: no chord is split
    piece_rows: tuple | None
    piece_fold: np.ndarray | None
    reports: tuple[LayerReport, ...]


def plan_layers(g: GCodeFile, chords: Chords, batches: Iterator[tuple], job: Job, *,
                options: PostprocessOptions) -> LayerPlans:
    """Plan every layer: batches of layers side by side, one target per batch."""
    n = len(chords.seg)
    angle = np.zeros(n)
    fold = np.zeros(n, dtype=bool)
    width_laid = np.full(n, np.nan)
    split_found: list[np.ndarray] = []  # the split chords, per batch
    rows_found: list[tuple] = []  # their pieces as arrays, per batch
    reports: list[LayerReport] = []
    prev = 0.0
    for layers, offset, target, areas, last in batches:
        rows = [chords.order[chords.bounds[k]:chords.bounds[k + 1]] for k in layers]
        counts = np.array([r.size for r in rows], dtype=np.int64)
        idx = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        lay_of = np.repeat(np.arange(len(layers)), counts)
        plan = None
        if idx.size:
            plan = _plan_batch(chords, idx, lay_of, offset, target, job, options=options,
                               previous=prev, last=last)
            angle[idx] = plan.angle
            fold[idx] = plan.fold
            width_laid[idx] = plan.width
            if plan.pieces:
                split_found.append(idx[np.fromiter(plan.pieces, np.int64, len(plan.pieces))])
                rows_found.append((idx[plan.piece_rows[0]], *plan.piece_rows[1:],
                                   plan.piece_fold))
            finite = plan.angle[np.isfinite(plan.angle)]
            if finite.size:
                prev = float(finite[-1])
        reports.extend(layer_reports(g, layers, areas, idx, counts, lay_of, plan,
                                     chords.length, chords.width))
    pieces, piece_rows, piece_fold = _gathered_pieces(split_found, rows_found)
    return LayerPlans(angle=angle, fold=fold, width_laid=width_laid, pieces=pieces,
                      piece_rows=piece_rows, piece_fold=piece_fold, reports=tuple(reports))


def _plan_batch(chords: Chords, idx: np.ndarray, lay_of: np.ndarray, offset: np.ndarray,
                target: object, job: Job, *, options: PostprocessOptions, previous: float,
                last: bool) -> Plan:
    """The plan of one batch's chords ``idx`` (``lay_of``: the layer of each within the
    batch, laid at ``offset``), starting from the angle ``previous``."""
    seg = chords.seg
    p0 = np.column_stack([seg["x0"][idx], seg["y0"][idx]]) + offset[lay_of]
    p1 = np.column_stack([seg["x1"][idx], seg["y1"][idx]]) + offset[lay_of]
    sm = chords.move[idx]
    chained = np.zeros(idx.size, dtype=bool)
    if idx.size > 1 and job.feed_policy == "xy":
        same = (sm[1:] == sm[:-1]) | ((sm[1:] == sm[:-1] + 1)
                                      & (np.abs(p0[1:] - p1[:-1]).max(axis=1) < 1e-9))
        chained[1:] = same & (lay_of[1:] == lay_of[:-1])
    planner = replace(options.orientation, narrow_beads=job.narrow_beads,
                      fold_pieces=job.feed_policy == "xy")
    return plan_orientations(p0, p1, chords.width[idx], target, job.nozzle, job.machine,
                             options=planner, previous=previous,
                             prepared_target=target, chained=chained,
                             interior=chords.interior[idx],
                             # the cores are the targets' until the last is built
                             workers=job.workers if last else 1)


def _gathered_pieces(split_found: list[np.ndarray], rows_found: list[tuple]
                     ) -> tuple[Mapping[int, list], tuple | None, np.ndarray | None]:
    """The pieces of every batch's split chords, by chord."""
    if not rows_found:
        return {}, None, None
    cols = [np.concatenate([r[c] for r in rows_found]) for c in range(5)]
    by_chord = np.argsort(cols[0], kind="stable")
    piece_rows = tuple(c[by_chord] for c in cols[:4])
    return PieceMap(np.concatenate(split_found), piece_rows), piece_rows, cols[4][by_chord]


# ----------------------------------------------------------------- rewriting


def rewrite_moves(g: GCodeFile, data: bytes, chords: Chords, plans: LayerPlans, job: Job, *,
                  options: PostprocessOptions) -> tuple[RewriteOutput, dict[int, int]]:
    """The slicer's file with the moves that need it rewritten
    (:func:`printability.postprocess.rewrite.rewrite`), and the moves turned per layer."""
    # an interior bead laid wider than planned keeps the slicer's volume: E follows the
    # width only where it is narrower (a wider footprint spreads the same bead)
    with np.errstate(invalid="ignore"):
        width_for_e = np.where(chords.interior & (plans.width_laid > chords.width)
                               & options.orientation.wider_interior, chords.width,
                               plans.width_laid)
    progress("rewriting the moves")
    return rewrite(SlicerFile(data, g, g.moves),
                   ChordPlan(chords.seg, chords.move, plans.angle, plans.fold, width_for_e,
                             chords.width, plans.pieces, job.heights, plans.piece_rows,
                             plans.piece_fold),
                   WriteSettings(job.writer, job.turns, job.e_policy, job.nozzle))


# ----------------------------------------------------------------- reporting


@dataclass(frozen=True)
class Estimates:
    """What the firmware's planner and the extruder make of the file, before and after."""

    before: PrintTime
    after: PrintTime
    #: mm of filament the extruding moves push
    filament_before: float
    filament_after: float


def rotary_axis(job: Job) -> RotaryAxis:
    """The machine's rotary axis under the run's letter."""
    return RotaryAxis(**{**job.machine.rotary_axis.__dict__, "letter": job.letter})


def run_notes(job: Job, axis: RotaryAxis, *, options: PostprocessOptions) -> list[str]:
    """The notes of the comment block and of the result (the print time's comes later)."""
    notes = [
        "lost area = dropped length x planned width (what no orientation can print)",
        f"tolerance = {options.tolerance:g} mm; E policy = {job.e_policy}; layer targets from "
        "the slicer's part extrusions" + (", the gaps inside the object filled"
                                          if options.interior else ""),
    ]
    if job.narrow_beads:
        notes.append("round nozzle no larger than the slicer's: it lays the slicer's own beads, "
                     "every move is kept as it is")
    if job.turns:
        notes.append(job.flavor.rotary_setup_note(axis))
    return notes


def estimate_print_times(g: GCodeFile, out: RewriteOutput, path: str, machine: Machine,
                         axis: RotaryAxis) -> Estimates:
    """The print time on the firmware's planner, before and after (the body has no header
    yet; comments take no time), and the filament pushed."""
    progress("estimating the print time")
    t_in = estimate_print_time(g, limits=machine.planner, rotary=axis)
    g_out = parse_gcode(b"".join(out.chunks), path=path) if out.rotary_words or out.changed \
        else g
    t_out = estimate_print_time(g_out, limits=machine.planner, rotary=axis) \
        if g_out is not g else t_in
    return Estimates(before=t_in, after=t_out, filament_before=filament(g.moves),
                     filament_after=filament(g_out.moves))


def header_lines_of(g: GCodeFile, job: Job, axis: RotaryAxis, reports: list[LayerReport],
                    notes: list[str]) -> list[str]:
    """The comment block (the nozzle, the machine, the version, the per-layer summary, the
    notes), and the rotary axis declared (Klipper registers it) and zeroed before any rotary
    word when the nozzle turns."""
    head = header_lines(version=__version__, nozzle=job.nozzle.spec, machine=job.machine.spec,
                        options=job.writer, mode="postprocessed", summary=layer_summary(reports),
                        notes=notes, flavor=job.flavor.name, e_mode=_e_mode(g.moves))
    if job.turns:
        head += job.flavor.declare_rotary(axis)
    return head


def _e_mode(moves: np.ndarray) -> str:
    """How the file's extruding moves count E: ``relative``, ``absolute`` or ``mixed``."""
    rel = (moves["flags"][moves["e"] > 0] & MF_E_RELATIVE) != 0
    if rel.all():
        return "relative"
    return "absolute" if not rel.any() else "mixed"


def with_header(g: GCodeFile, out: RewriteOutput, head: list[str]) -> bytes:
    """The rewritten file with the comment block before its first command, in the file's
    line ending (``out``'s chunks, one per line up to there, get the block)."""
    lines = g.lines
    first_cmd = first_command_line(lines)
    eol = eol_of(g.line(first_cmd)) if len(lines) else b"\n"
    block = b"".join(h.encode("utf-8") + eol for h in head)
    body = out.chunks
    body.insert(first_cmd, block)
    return b"".join(body)


def check_something_printed(reports: list[LayerReport], path: str, job: Job, *,
                            options: PostprocessOptions) -> None:
    """Refuse a run whose nozzle prints none of the part (unless ``allow_empty``)."""
    n_part = sum(r.moves for r in reports)
    # (printed_length is a difference of sums: a few 1e-13 mm when nothing is printed)
    if n_part and not options.allow_empty and \
            not any(r.printed_length > 1e-6 for r in reports):
        raise NozzleTooLargeError(
            f"{path}: nozzle {job.nozzle.spec} on machine {job.machine.spec} can print none of "
            f"the part's {n_part} extrusions (every feature is narrower than the nozzle lays at "
            "any orientation); the file is left unchanged. Choose a smaller nozzle, or pass "
            "--allow-empty to write it anyway")


def run_result(path: str, g: GCodeFile, out: RewriteOutput, job: Job, *, n_header: int,
               reports: list[LayerReport], notes: list[str], estimates: Estimates,
               t_start: float) -> PostprocessResult:
    """The outcome of a run that rewrote the file (``n_header``: the comment block's lines)."""
    n_in = len(g.lines)
    return PostprocessResult(
        path=path, output=path, already_processed=False, lines_in=n_in,
        lines_out=n_in + out.inserted + n_header, changed_lines=out.changed,
        inserted_lines=out.inserted + n_header, rotary_words=out.rotary_words,
        layers=tuple(reports), elapsed=time.perf_counter() - t_start, nozzle=job.nozzle.spec,
        machine=job.machine.spec, notes=tuple(notes), print_time_in=estimates.before.total,
        print_time_out=estimates.after.total, filament_in=estimates.filament_before,
        filament_out=estimates.filament_after,
    )
