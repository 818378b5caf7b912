"""Generate a complete G-code file for a T-T-R machine from layers (``printability generate``).

For every layer of a :class:`~printability.model.layers.LayerStack` (an STL sliced
by :func:`printability.sources.load_layers`, slice outlines, a drawing...):

1. perimeters and infill are laid out inside G
   (:mod:`printability.planning.toolpaths`): walls at the nozzle's narrowest
   bead, infill at its widest;
2. every move gets the orientation laying the planned width that keeps the
   swept nozzle inside G, turning least; what no orientation can print is cut
   away (:func:`printability.planning.orientation.plan_orientations`, the same
   MMC-safe planner as the post-processor);
3. groups are ordered by a greedy TSP tour (networkx);
4. the writer (:class:`gcode.writer.Emitter`) emits it with the machine's
   flavor, feed policy, rotary letter and limits, E from the bead
   cross-section actually laid (the width at the chosen orientation), and the
   temperatures, speeds and retraction of the machine profile's
   ``[temperatures]``, ``[speeds]``, ``[retraction]`` and ``[gcode]`` tables
   (see ``printability/data/machines/ttr.toml``).

The file carries PrusaSlicer-style ``;LAYER_CHANGE`` / ``;Z:`` / ``;HEIGHT:`` /
``;TYPE:`` / ``;WIDTH:`` comments, so :mod:`gcode` (and ``printability
analyze``) read it back, and it is written atomically.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity

from gcode import parse_gcode
from gcode.flavors import Flavor, RotaryAxis
from gcode.printtime import estimate_print_time, format_duration
from gcode.writer import Emitter, WriterOptions, header_lines
from printability import __version__
from printability.errors import InputError, PrintabilityOSError
from printability.generate._emit_kernel import emit
from printability.generate._group_kernel import measures, orifice_of, pieces_of
from printability.model.layers import LayerStack
from printability.model.machine import Machine, parse_machine
from printability.model.nozzle import Nozzle, parse_nozzle
from printability.options import BEAD_MODELS, FEED_POLICIES
from printability.planning.footprints import grown_target
from printability.planning.orientation import OrientationOptions, plan_orientations
from printability.planning.toolpaths import infill_lines, order_groups, perimeter_loops

__all__ = ["GenerateOptions", "GenerateResult", "generate_file", "generate_gcode"]

_TYPE_NAMES = {"outer_wall": "External perimeter", "inner_wall": "Perimeter",
               "sparse_infill": "Internal infill"}

@dataclass(frozen=True)
class GenerateOptions:
    """How to lay out and write the part.

    Attributes
    ----------
    perimeters
        Number of wall loops.
    infill_angle
        Direction of the infill lines on the first layer, degrees (turned
        by 90° every layer).
    infill_spacing
        Distance between infill lines, mm (None: the widest bead the nozzle lays).
    wall_width
        Planned wall bead width, mm (None: the narrowest bead the nozzle lays).
    feed_policy, letter
        Override the machine's.
    unwind
        Cabled head: bring the rotary axis back towards 0 on travel moves.
    relative_e
        M83 (True) or M82.
    tolerance
        How far the swept nozzle may stand outside G, mm.
    center
        Move the part to the middle of the machine's bed (every built-in
        machine has one; a profile without ``[bed]`` keeps the part's own
        coordinates). A part larger than the bed is an error either way.
    """

    perimeters: int = 2
    infill_angle: float = 45.0
    infill_spacing: float | None = None
    wall_width: float | None = None
    feed_policy: str | None = None
    letter: str | None = None
    unwind: bool = False
    relative_e: bool = True
    tolerance: float = 1e-3
    center: bool = True
    orientation: OrientationOptions = field(default_factory=OrientationOptions)


@dataclass(frozen=True)
class GenerateResult:
    """What was generated (lengths in mm, areas in mm²)."""

    path: str | None
    layers: int
    lines: int
    extruded_length: float
    dropped_length: float
    rotations: int
    elapsed: float
    summary: tuple[dict[str, float], ...]
    print_time: float | None = None  # s on the firmware's planner (gcode.printtime)


def _profile(machine: Machine, table: str) -> Mapping[str, Any]:
    value = machine.profile.get(table, {}) if machine.profile else {}
    if not isinstance(value, Mapping):
        raise InputError(f"machine {machine.name!r}: [{table}] must be a table")
    return value


def _num(machine: Machine, table: str, key: str, default: float) -> float:
    v = _profile(machine, table).get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise InputError(f"machine {machine.name!r}: [{table}] {key} expects a non-negative "
                         f"number; found {v!r}")
    return float(v)


def _template(machine: Machine, key: str, default: list[str], values: Mapping[str, float]):
    text = _profile(machine, "gcode").get(key)
    lines = default if text is None else str(text).splitlines()
    out = []
    for ln in lines:
        for k, v in values.items():
            ln = ln.replace("{" + k + "}", f"{v:g}")
        out.append(ln)
    return out


def generate_gcode(
    layers: LayerStack,
    nozzle: str | Nozzle,
    machine: str | Machine = "ttr",
    *,
    options: GenerateOptions = GenerateOptions(),
    on_progress: Callable[[str, int, int], None] | None = None,
) -> tuple[str, GenerateResult]:
    """Plan and write the G-code of a part.

    Parameters
    ----------
    layers
        The part's layers (a planar input of height 0 gets the wall width as
        its layer height).
    nozzle, machine
        SPECs or objects; the machine's profile gives flavor, feed policy,
        rotary letter and limits, temperatures, speeds, retraction, start/end G-code.
    options
        See :class:`GenerateOptions`.
    on_progress
        Called as ``on_progress(stage, done, total)``: "planning the layers" after each
        layer (``done`` of ``total``), then "estimating the print time" (``total`` 0).

    Returns
    -------
    (text, GenerateResult)

    Raises
    ------
    InputError
        Bad options or profile values.
    """
    t_start = time.perf_counter()
    noz = parse_nozzle(nozzle)
    mach = parse_machine(machine)
    job = _job_settings(noz, mach, options)
    turns, policy, wopts, temps = job.turns, job.policy, job.wopts, job.temps
    v_per, v_inf, v_first = job.feeds
    w_wall, w_fill = job.w_wall, job.w_fill
    travel = job.travel

    shift = _placement(layers, mach, center=options.center)
    em = _open_program(job, mach)
    pos = np.array([0.0, 0.0])
    summary: list[dict[str, float]] = []
    extruded = dropped = 0.0
    prev_angle = 0.0
    report = on_progress or (lambda stage, done, total: None)
    report("planning the layers", 0, len(layers))
    for li, layer in enumerate(layers):
        h = layer.height if layer.height > 0 else w_wall / 2
        region = layer.region
        if shift != (0.0, 0.0):
            region = shapely.affinity.translate(region, *shift)
        walls, interior = perimeter_loops(region, w_wall, options.perimeters)
        fill = infill_lines(interior, w_fill, options.infill_angle + 90.0 * (li % 2))
        groups = order_groups(walls + fill, pos)
        # coordinates are rounded when written: keep that displacement inside the tolerance
        tgt = grown_target(region, options.tolerance - wopts.rounding)
        em.raw(";LAYER_CHANGE")
        em.raw(f";Z:{layer.z:g}")
        em.raw(f";HEIGHT:{h:g}")
        if li == 1:
            em.raw(f"M104 S{temps['nozzle']:g}")
            em.raw(f"M140 S{temps['bed']:g}")
        layer_drop = 0.0
        layer_len = 0.0
        first_move = True
        for grp in groups:
            # one planning call per group: its chords in print order
            chords = _group_chords(grp)
            if chords is None:
                continue
            p0, p1, chained = chords
            plan = plan_orientations(p0, p1, np.full(len(p0), grp.width), region, noz, mach,
                                     options=options.orientation, previous=prev_angle,
                                     prepared_target=tgt,
                                     chained=chained if policy == "xy" else None)
            feed = v_first if li == 0 else (v_inf if grp.kind == "sparse_infill" else v_per)
            em.raw(f";TYPE:{_TYPE_NAMES[grp.kind]}")
            em.raw(f";WIDTH:{grp.width:g}")
            acc = np.array([extruded, layer_len, layer_drop, prev_angle])
            run = _pieces(p0, p1, plan, noz, turns=turns, width=grp.width, acc=acc)
            extruded, layer_len, layer_drop, prev_angle = acc.tolist()
            done = emit(em, *run, z=layer.z, height=h, feed=feed, travel=travel,
                        first_move=first_move)
            if done is None:  # declined: the emitter itself (the same lines, or its error)
                done = _emit_run(em, run, z=layer.z, height=h, feed=feed, travel=travel,
                                 first_move=first_move)
            first_move = done
            pos = np.array([em.x, em.y])
        dropped += layer_drop
        summary.append({"z": layer.z, "target_area": layer.area,
                        "lost_area": layer_drop * w_wall,
                        "dropped_moves": 0, "dropped_length": layer_drop, "split_moves": 0})
        report("planning the layers", li + 1, len(layers))
    text, print_time = _close_program(em, job, mach, noz, options, summary, report)
    res = GenerateResult(path=None, layers=len(layers), lines=text.count("\n"),
                         extruded_length=extruded, dropped_length=dropped,
                         rotations=em.rotations, elapsed=time.perf_counter() - t_start,
                         summary=tuple(summary), print_time=print_time)
    return text, res


@dataclass(frozen=True)
class _Job:
    """The settings of one generation, read from the machine profile and the options."""

    turns: bool  # the machine turns the nozzle
    flavor: Flavor  # the machine's firmware flavor
    policy: str  # feed policy
    wopts: WriterOptions
    temps: dict[str, float]  # nozzle, bed, first_layer_nozzle, first_layer_bed, °C
    feeds: tuple[float, float, float]  # perimeter, infill, first layer, mm/min
    travel: tuple[float, float, float, float, float]  # feed, retract length/feed, min, lift
    w_wall: float  # wall bead width, mm
    w_fill: float  # infill spacing, mm


def _job_settings(noz: Nozzle, mach: Machine, options: GenerateOptions) -> _Job:
    """Check the options against the machine and read its profile's tables.

    Raises
    ------
    InputError
        Bad options or profile values.
    """
    if options.perimeters < 0:
        raise InputError(f"perimeters must be >= 0; got {options.perimeters}")
    period = noz.symmetry_period
    turns = mach.turns(noz)
    flavor = mach.firmware()
    policy = FEED_POLICIES.check(options.feed_policy or mach.feed_policy_for(flavor))
    if policy == "inverse-time" and not flavor.inverse_time:
        raise InputError(f"feed policy inverse-time needs G93, which the {flavor.name} flavor "
                         "does not have; use feed policy xy (or the generic flavor's "
                         "euclidean)")
    bead_model = str(_profile(mach, "extruder").get("bead_model", "rounded"))
    bead_model = BEAD_MODELS.check(bead_model)
    full = mach.full_turn and not options.unwind
    wopts = WriterOptions(
        letter=(options.letter or mach.rotary_letter).upper(),
        period=period if turns else 0.0,
        angle_min=-math.inf if full else (mach.angle_min if mach.has_rotary else 0.0),
        angle_max=math.inf if full else (mach.angle_max if mach.has_rotary else 0.0),
        unwind=options.unwind, feed_policy=policy, relative_e=options.relative_e,
        filament_diameter=mach.filament_diameter, bead_model=bead_model,
        rotary_feed=60.0 * _num(mach, "speeds", "rotary", mach.rotary_axis.max_speed),
    )
    temps = {
        "nozzle": _num(mach, "temperatures", "nozzle", 210.0),
        "bed": _num(mach, "temperatures", "bed", 60.0),
    }
    temps["first_layer_nozzle"] = _num(mach, "temperatures", "first_layer_nozzle", temps["nozzle"])
    temps["first_layer_bed"] = _num(mach, "temperatures", "first_layer_bed", temps["bed"])
    v_per = 60.0 * _num(mach, "speeds", "perimeter", 30.0)
    v_inf = 60.0 * _num(mach, "speeds", "infill", 50.0)
    v_trav = 60.0 * _num(mach, "speeds", "travel", 150.0)
    v_first = 60.0 * _num(mach, "speeds", "first_layer", 20.0)
    r_len = _num(mach, "retraction", "length", 0.8)
    r_feed = 60.0 * _num(mach, "retraction", "speed", 35.0)
    r_min = _num(mach, "retraction", "min_travel", 1.0)
    lift = _num(mach, "retraction", "lift", 0.0)

    w_wall = options.wall_width or noz.min_width
    w_fill = options.infill_spacing or noz.max_width
    if w_wall <= 0 or w_fill <= 0:
        raise InputError("wall width and infill spacing must be positive lengths in mm")
    return _Job(turns, flavor, policy, wopts, temps, (v_per, v_inf, v_first),
                (v_trav, r_len, r_feed, r_min, lift), w_wall, w_fill)


def _open_program(job: _Job, mach: Machine) -> Emitter:
    """The emitter, with the program's start: the machine's start G-code, the preamble, and
    the rotary axis declared when the nozzle turns."""
    em = Emitter(job.wopts)
    em.comment("generated by printability " + __version__)
    em.extend(_template(mach, "start", list(job.flavor.start_gcode()), job.temps))
    em.preamble()
    if job.turns:
        axis = RotaryAxis(**{**mach.rotary_axis.__dict__, "letter": job.wopts.letter})
        em.extend(job.flavor.declare_rotary(axis))
    return em


def _group_chords(grp) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A group's chords in print order, zero-length ones left out: starts, ends, and whether
    each continues the path of the one before; None when none is left."""
    chords = [(p[:-1], p[1:]) for p in grp.paths]
    p0 = np.vstack([c[0] for c in chords])
    p1 = np.vstack([c[1] for c in chords])
    path_id = np.concatenate([np.full(len(c[0]), k) for k, c in enumerate(chords)])
    keep = np.hypot(*(p1 - p0).T) > 1e-6
    p0, p1, path_id = p0[keep], p1[keep], path_id[keep]
    if len(p0) == 0:
        return None
    chained = np.zeros(len(p0), dtype=bool)
    chained[1:] = path_id[1:] == path_id[:-1]
    return p0, p1, chained


def _emit_run(em: Emitter, run: tuple, *, z: float, height: float, feed: float,
              travel: tuple, first_move: bool) -> bool:
    """Write a group's pieces with the emitter itself (where the compiled
    :func:`printability.generate._emit_kernel.emit` declines): the same lines, or the
    emitter's error.
    Returns whether the next piece still is the layer's first move."""
    for ax, ay, bx, by, phi, w, fold in zip(*run, strict=True):
        if em.x is None or math.hypot(ax - em.x, ay - em.y) > 1e-6 or first_move:
            _travel(em, (ax, ay), z, None if math.isnan(phi) else phi, *travel)
            first_move = False
        em.extrude(bx, by, feed=feed, width=w, height=height,
                   orientation=None if math.isnan(phi) else phi,
                   turn_while_moving=None if math.isnan(fold) else fold)
    return first_move


def _close_program(em: Emitter, job: _Job, mach: Machine, noz: Nozzle,
                   options: GenerateOptions, summary: list[dict[str, float]],
                   report: Callable[[str, int, int], None]) -> tuple[str, float]:
    """End the program (retract, postamble, the machine's end G-code), estimate its print
    time, and put the header on it: the whole text, and the print time (s)."""
    _, r_len, r_feed, _, _ = job.travel
    em.retract(r_len, feed=r_feed)
    em.postamble()
    em.extend(_template(mach, "end", list(job.flavor.end_gcode()), job.temps))
    notes = [f"walls at {job.w_wall:g} mm, infill spacing {job.w_fill:g} mm, "
             f"{options.perimeters} perimeters",
             "lost area here = planned path left out (no nozzle angle keeps the bead inside "
             "the part) x wall width, not analyze's lost area (the part no nozzle position "
             "covers)"]
    if job.turns:
        notes.append(job.flavor.rotary_setup_note(mach.rotary_axis))
    body = em.text()
    report("estimating the print time", 0, 0)
    t = estimate_print_time(parse_gcode(body.encode()), limits=mach.planner,
                            rotary=RotaryAxis(**{**mach.rotary_axis.__dict__,
                                                 "letter": job.wopts.letter}))
    notes.append(f"estimated print time on the firmware's planner (Klipper's look-ahead, the "
                 f"machine's [planner] limits): {format_duration(t.total)}")
    head = header_lines(version=__version__, nozzle=noz.spec, machine=mach.spec,
                        options=job.wopts, mode="generated", summary=summary, notes=notes,
                        flavor=job.flavor.name)
    text = "".join(ln + "\n" for ln in head) + body
    return text, t.total


def _placement(layers: LayerStack, mach: Machine, *, center: bool) -> tuple[float, float]:
    """The XY shift that puts the part on the machine's bed (its middle with ``center``).

    Raises
    ------
    InputError
        The part is larger than the bed, or (without ``center``) stands off it.
    """
    regions = [layer.region for layer in layers if not layer.region.is_empty]
    if mach.bed is None or not regions:
        return (0.0, 0.0)
    bounds = np.array([r.bounds for r in regions])
    x0, y0 = bounds[:, 0].min(), bounds[:, 1].min()
    x1, y1 = bounds[:, 2].max(), bounds[:, 3].max()
    bx0, bx1, by0, by1 = mach.bed
    if x1 - x0 > bx1 - bx0 or y1 - y0 > by1 - by0:
        raise InputError(f"the part ({x1 - x0:.1f} mm × {y1 - y0:.1f} mm) is larger than the "
                         f"bed of machine {mach.name!r} ({bx1 - bx0:g} mm × {by1 - by0:g} mm, "
                         f"x {bx0:g}..{bx1:g}, y {by0:g}..{by1:g}); scale the part or use a "
                         "machine profile with a larger [bed]")
    if center:
        return ((bx0 + bx1) / 2 - (x0 + x1) / 2, (by0 + by1) / 2 - (y0 + y1) / 2)
    if x0 < bx0 or x1 > bx1 or y0 < by0 or y1 > by1:
        raise InputError(f"the part spans x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f} mm, off "
                         f"the bed of machine {mach.name!r} (x {bx0:g}..{bx1:g}, y "
                         f"{by0:g}..{by1:g}); leave centring on or move the part")
    return (0.0, 0.0)


def _pieces(p0: np.ndarray, p1: np.ndarray, plan, noz: Nozzle, *, turns: bool, width: float,
            acc: np.ndarray) -> tuple:
    """The pieces of one group's moves as :func:`printability.generate._emit_kernel.emit` takes them
    (columns ax, ay, bx, by, phi, w, fold; NaN for no orientation, no turn while moving),
    with ``acc = [extruded, layer length, layer dropped, last angle]`` updated in order.

    Compiled (:func:`printability.generate._group_kernel.pieces_of`) for circles, ellipses and
    rectangles; in Python, the same operations, for polygon orifices.
    """
    n = len(p0)
    seg_len = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1])
    split = np.zeros(n, dtype=bool)
    if plan.pieces:
        split[np.fromiter(plan.pieces, np.int64, len(plan.pieces))] = True
    move, rt0, rt1, rphi = (np.asarray(c) for c in plan.piece_rows)
    if measures(noz.footprints):
        lo = np.searchsorted(move, np.arange(n), "left")
        hi = np.searchsorted(move, np.arange(n), "right")
        group = (np.ascontiguousarray(p0, dtype=float), np.ascontiguousarray(p1, dtype=float),
                 seg_len, np.asarray(plan.angle, dtype=float), np.asarray(plan.fold, dtype=bool),
                 split, lo, hi)
        rows = (rt0.astype(float), rt1.astype(float), rphi.astype(float))
        return pieces_of(group, rows, orifice_of(noz.footprints), float(noz.mount_angle),
                         turns, float(width), acc)
    extruded, layer_len, layer_drop, prev_angle = acc.tolist()
    lens = seg_len.tolist()
    angles = plan.angle.tolist()
    folds = plan.fold.tolist()
    starts = p0.tolist()
    ends = p1.tolist()
    run: tuple[list[float], ...] = ([], [], [], [], [], [], [])
    for i in range(n):
        ax0, ay0 = starts[i]
        bx1, by1 = ends[i]
        dx = bx1 - ax0
        dy = by1 - ay0
        layer_len += lens[i]
        if split[i]:
            pieces = [(p.t0, p.t1, p.angle) for p in plan.pieces[i]]
            layer_drop += lens[i] * (1 - sum(b - a for a, b, _ in pieces))
        else:
            pieces = [(0.0, 1.0, angles[i])]
        for t0, t1, phi in pieces:
            ax, ay = ax0 + t0 * dx, ay0 + t0 * dy
            bx, by = ax0 + t1 * dx, ay0 + t1 * dy
            direction = math.degrees(math.atan2(by - ay, bx - ax))
            w = noz.bead_width(direction, phi) if turns else width
            fold = abs(angles[i] - angles[i - 1]) if not split[i] and folds[i] else math.nan
            for column, v in zip(run, (ax, ay, bx, by, phi if turns else math.nan, w, fold),
                                 strict=True):
                column.append(v)
            extruded += math.hypot(bx - ax, by - ay)
            if turns:
                prev_angle = phi
    acc[:] = extruded, layer_len, layer_drop, prev_angle
    return run


def _travel(em: Emitter, to: np.ndarray, z: float, orientation: float | None, feed: float,
            r_len: float, r_feed: float, r_min: float, lift: float) -> None:
    """Move to ``to`` without extruding: retract, lift, move (turning), lower, unretract."""
    far = em.x is None or math.hypot(to[0] - em.x, to[1] - em.y) >= r_min
    if far:
        em.retract(r_len, feed=r_feed)
        if lift > 0 and em.z is not None:
            em.travel(z=z + lift, feed=feed)
    em.travel(float(to[0]), float(to[1]), z=z if not (far and lift > 0) else None, feed=feed,
              orientation=orientation)
    if far:
        if lift > 0:
            em.travel(z=z, feed=feed)
        em.unretract(r_len, feed=r_feed)


def generate_file(
    input_path: str | os.PathLike[str] | LayerStack,
    output: str | os.PathLike[str],
    nozzle: str | Nozzle,
    machine: str | Machine = "ttr",
    *,
    options: GenerateOptions = GenerateOptions(),
    layer_height: float | None = None,
    first_layer_height: float | None = None,
    units: str | None = None,
    on_progress: Callable[[str, int, int], None] | None = None,
) -> GenerateResult:
    """Load layers (any source :func:`printability.sources.load_layers` reads), generate, and
    write the G-code atomically to ``output``.

    ``on_progress(stage, done, total)`` hears "reading NAME", the stages of
    :func:`generate_gcode` and "writing NAME" (``total`` 0: a stage with no count).
    """
    report = on_progress or (lambda stage, done, total: None)
    if isinstance(input_path, LayerStack):
        layers = input_path
    else:
        from printability.sources import load_layers

        report(f"reading {Path(input_path).name}", 0, 0)
        layers = load_layers(input_path, layer_height=layer_height,
                             first_layer_height=first_layer_height, units=units)
    text, res = generate_gcode(layers, nozzle, machine, options=options, on_progress=report)
    out = Path(output)
    from printability.postprocess.files import write_atomic

    report(f"writing {out.name}", 0, 0)
    try:
        write_atomic(out, text.encode("utf-8"))
    except OSError as exc:
        raise PrintabilityOSError(f"{out}: cannot write the G-code ({exc.strerror or exc})") \
            from None
    return GenerateResult(**{**res.__dict__, "path": str(out)})
