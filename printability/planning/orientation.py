"""Choose the nozzle orientation of every extruding move (MMC-safe).

A move from p₀ to p₁ at the constant orientation φ deposits inside the swept
footprint ``[p₀, p₁] ⊕ R(φ)A⁰``. For a convex orifice that is the convex hull
of the footprint placed at both ends; a non-convex polygon is split into
triangles and each is swept. The move is *admissible* at φ when that swept
region lies inside the layer target G grown by ``tolerance`` (equivalently:
the segment lies in the motion restriction P_φ = G ⊖ R(φ)A⁰, up to the
tolerance). Footprints are tested with their *outer* polygonal
approximation, so curved orifices are never under-estimated.
The footprints and that test are :mod:`printability.planning.footprints`.

Search order, cheapest first (shapely's vectorised predicates on a prepared
G):

1. the *preferred* orientation of each move: the one whose bead width
   (:meth:`Nozzle.bead_width`) is closest to the planned width, among the
   equivalent solutions the one nearest the previous move's (turn least);
2. for the moves that do not fit, the other orientation laying that width, then
   orientations of a grid (``search_step``) in rounds of increasing cost
   (width error first, then the turn);
3. for the moves that still do not fit anywhere, the longest middle that fits
   at the two orientations laying the planned width (else at the grid's two
   cheapest) is kept, and the rest is searched at every orientation, whole, then
   in pieces of up to twice ``split_length``, then the pieces that still fit
   nowhere halved (down to ``split_length``); what fits nowhere then is
   dropped, and reported; the pieces next to a split move's longest one then take its
   orientation where it fits (:func:`~printability.planning._passes.align_pieces`);
4. along each path, the admissible orientations (of a few per whole move: those laying
   the planned width, the grid, fixed angles to the motion) whose turns cost least,
   a turn made standing still (larger than ``fold_max``, or not admissible during
   the move) and a reversal costing extra (:func:`~printability.planning.turns.least_turning`);
5. which turns are made during a move or a piece of a split one (``Plan.fold``,
   ``Plan.piece_fold``: :func:`~printability.planning._passes.fold_flags`, with the turning
   footprint tested in steps of at most :data:`~printability.planning.turns.TURN_STEP`,
   :func:`~printability.planning.turns.turning_fits`).

The moves and what they are tested against travel as one
:class:`~printability.planning.plan.PlanContext`; the result is a
:class:`~printability.planning.plan.Plan`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from shapely.geometry.base import BaseGeometry

from printability.base.arrays import take_rows
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.planning import footprints as fp
from printability.planning._passes import (
    align_pieces,
    drop_side_pieces,
    fold_flags,
    other_solution,
    reachable,
    smooth,
)
from printability.planning._plan_kernels import chain_nearest, piece_losses, width_picks
from printability.planning._search import cost_order, search_ordered, split_many, tried_counts
from printability.planning.footprints import (
    convex_pieces,
    fits,
    swept_footprints,
    swept_rings,
)
from printability.planning.plan import OrientedPiece, PieceMap, Plan, PlanContext, piece_rows_of
from printability.planning.turns import least_turning

__all__ = [
    "OrientationOptions",
    "OrientedPiece",
    "PieceMap",
    "Plan",
    "PlanContext",
    "candidate_orientations",
    "convex_pieces",
    "fits",
    "piece_losses",
    "piece_rows_of",
    "plan_context",
    "plan_orientations",
    "swept_footprints",
    "swept_rings",
    "width_table",
]


@dataclass(frozen=True)
class OrientationOptions:
    """Tolerances and policies of the orientation search.

    Attributes
    ----------
    tolerance
        How far (mm) a swept footprint may stand outside the target: covers
        the rounding of the slicer's coordinates and of the polygonal arcs.
    quad_segs
        Segments per quarter of a curved orifice (outer approximation).
    search_step
        Angular step of the search when the preferred orientation fails, degrees.
    width_slack
        Orientations whose bead width is within this (mm) of the best
        achievable one are ranked by turn only.
    split_length
        The split's resolution, mm (None: a quarter of the nozzle radius, at
        least 0.05 mm): what fits nowhere is cut into pieces of up to twice
        this, and a piece that still fits nowhere is halved: what is dropped
        goes in pieces of at most this length.
    fold_max
        Largest turn (degrees) made during an extruding move rather than
        standing still.
    side_piece_widths
        Pieces of a split move that need a turn of their own and are at most this
        many planned bead widths long are left out (see
        :func:`~printability.planning._passes.drop_side_pieces`):
        a turn standing still costs more print time than such a fleck is worth.
        0 keeps every piece that fits.
    wider_interior
        Whether the moves :func:`plan_orientations` is told are interior (inner walls,
        infill) may lay a bead wider than planned where it fits, rather than turn at
        every change of direction (False: every move lays the planned width).
    narrow_beads
        A round nozzle lays the planned width where the plan is narrower than
        the orifice (the slicer's own model of *its* nozzle: bridges and gap
        fill are under-extruded on purpose), so its footprint there is the
        disk of the planned width. Only true for the nozzle the file was
        sliced for (or a smaller one); otherwise the whole orifice counts (the
        post-processor sets it from the job).
    fold_pieces
        Whether the turns into the pieces of split moves may be made during them too
        (``Plan.piece_fold``; with ``chained`` given; the post-processor sets it from the
        feed policy: only where F is the XY feed).
    """

    tolerance: float = 1e-3
    quad_segs: int = 16
    search_step: float = 10.0
    width_slack: float = 0.02
    split_length: float | None = None
    fold_max: float = 20.0
    side_piece_widths: float = 1.0
    wider_interior: bool = True
    narrow_beads: bool = False
    fold_pieces: bool = True


@functools.lru_cache(maxsize=32)
def _width_table_cached(nozzle: Nozzle, step: float) -> tuple[np.ndarray, np.ndarray]:
    beta = np.arange(0.0, 360.0, step)
    width = np.array([nozzle.bead_width(0.0, b) for b in beta])
    beta.setflags(write=False)
    width.setflags(write=False)
    return beta, width


def width_table(nozzle: Nozzle, *, step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Bead width as a function of the orientation relative to the motion.

    Returns
    -------
    beta : ndarray
        Orientation minus direction of motion, degrees in [0, 360).
    width : ndarray
        Bead width, mm (``bead_width(0, beta)``; the width only depends on
        the difference).
    """
    return _width_table_cached(nozzle, step)


def candidate_orientations(machine: Machine, nozzle: Nozzle, *, step: float) -> np.ndarray:
    """Orientations the machine can take, sampled every ``step`` degrees (one period)."""
    period = nozzle.symmetry_period
    if not machine.turns(nozzle):
        return np.array([0.0])
    lo, hi = machine.angle_min, machine.angle_max
    span = min(hi - lo, period if period else 360.0)
    n = max(1, math.ceil(span / step - 1e-9))
    full = span >= (period or 360.0) - 1e-9
    return lo + np.arange(n + (0 if full else 1)) * (span / n)


@functools.lru_cache(maxsize=8)
def _half_turn_distance_cached(beta: bytes) -> np.ndarray:
    b = np.frombuffer(beta)
    out = np.abs((b[None, :] - b[:, None] + 90.0) % 180.0 - 90.0)
    out.setflags(write=False)
    return out


def _half_turn_distance(beta: np.ndarray) -> np.ndarray:
    """Row j: distance of every ``beta`` from ``beta[j]`` modulo 180°, degrees (cached).

    The same operations, element by element, as computing it for each move's pick.
    """
    return _half_turn_distance_cached(np.ascontiguousarray(beta, dtype=float).tobytes())


def _exact_widths(nozzle: Nozzle, w: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Per planned width ``w``, the relative orientation next to the table pick ``b``
    (degrees) that lays ``w`` to within the bisection's last bit, never wider.

    The table (:func:`width_table`, ``step`` apart) misses a width by up to
    ``step/2`` × the slope: for the ellipse 0.8 × 0.3 and a 0.45 mm plan its 27.0°
    lays 0.45096 mm, which leaves no room in a target that is just the planned bead
    grown by a fraction of τ (τ = 1 µm; :data:`~printability.planning.beadunion.SIDE`):
    every such move was refused there and laid at a narrower grid orientation instead.
    Here the width is bisected between ``b`` and the neighbouring entry on the other
    side of ``w``, keeping the end that is not wider
    (:meth:`~printability.model.nozzle.Nozzle.bead_widths`). Where neither neighbour lies
    across ``w`` (a width beyond the nozzle's range, an extremum) the pick stays.
    Cost: O(len(w)) per step of the bisection, about 50 steps (until every bracket is
    down to adjacent floats).
    """
    b = np.asarray(b, dtype=float)
    out = b.copy()
    zero = np.zeros_like(b)
    wb = nozzle.bead_widths(zero, b)
    below = nozzle.bead_widths(zero, b - step)
    above = nozzle.bead_widths(zero, b + step)
    wide = wb > w
    # the neighbour across w: narrower than w where b is wider, wider where b is narrower
    other = np.where(wide, np.where(below < w, b - step, np.where(above < w, b + step, np.nan)),
                     np.where(below > w, b - step, np.where(above > w, b + step, np.nan)))
    todo = np.isfinite(other) & (wb != w)
    inner = np.where(wide, other, b)[todo]  # bead width <= w here
    outer = np.where(wide, b, other)[todo]  # and > w here
    target = w[todo]
    along = np.zeros_like(inner)
    # about 50 steps take a bracket of 0.5° to adjacent floats; the cap of 60 only binds
    # next to 0°, where it leaves 0.5°/2**60, far below any width's rounding
    for _ in range(60):
        mid = 0.5 * (inner + outer)
        if np.all((mid == inner) | (mid == outer)):
            break  # every bracket is down to adjacent floats: more steps change nothing
        fits = nozzle.bead_widths(along, mid) <= target
        inner = np.where(fits, mid, inner)
        outer = np.where(fits, outer, mid)
    out[todo] = inner
    return out


def preferred_orientations(direction: np.ndarray, widths: np.ndarray, nozzle: Nozzle,
                           machine: Machine, *, previous: float = 0.0,
                           return_candidates: bool = False):
    """Per move, the orientation laying the planned width, turning least.

    The bead width only depends on the orientation relative to the motion
    and repeats every 180°; of the (usually two) relative orientations that
    give the width closest to the plan (the width table's picks, then bisected to
    lay the plan exactly and never wider: :func:`_exact_widths`), the one whose
    equivalent is nearest the previous move's orientation is taken. NaN widths
    prefer moving along the nozzle's narrowest extent.
    """
    n = len(direction)
    period = nozzle.symmetry_period
    per = period if period else 360.0
    beta_all, wtab_all = width_table(nozzle)
    half = beta_all < 180.0  # the width repeats every 180°
    beta, wtab = beta_all[half], wtab_all[half]
    w_all = np.where(np.isfinite(widths), widths, wtab.min())
    # a slicer plans a handful of distinct widths: each row depends on its width only
    w, inverse = np.unique(w_all, return_inverse=True)
    b1, b2 = width_picks(np.ascontiguousarray(w), np.ascontiguousarray(wtab),
                         np.ascontiguousarray(beta), _half_turn_distance(beta))
    both = _exact_widths(nozzle, np.concatenate([w, w]), np.concatenate([b1, b2]),
                         float(beta[1] - beta[0]))
    b1, b2 = both[:w.size], both[w.size:]
    b1 = b1[inverse.reshape(-1)]
    b2 = b2[inverse.reshape(-1)]
    # candidates: direction + b (+180 is the same width), unwrap sequentially
    c1 = (direction + b1).tolist()
    c2 = (direction + b2).tolist()
    reach = machine.has_rotary and not machine.covers_period(per)
    if not reach:
        out = chain_nearest(np.asarray(c1, dtype=float), np.asarray(c2, dtype=float),
                            float(per), float(previous))
        if return_candidates:
            return out, np.asarray(c1), np.asarray(c2)
        return out
    out = np.empty(n)
    prev = previous
    for i in range(n):
        best = None
        for c in (c1[i], c2[i], c1[i] + 180.0, c2[i] + 180.0):
            if reach and not reachable(np.array([c]), machine, per)[0]:
                continue
            near = c + per * round((prev - c) / per)
            if best is None or abs(near - prev) < abs(best - prev):
                best = near
        if best is None:  # nothing reachable lays the width: closest reachable orientation
            best = float(np.clip(prev, machine.angle_min, machine.angle_max))
        out[i] = best
        prev = best
    if return_candidates:
        return out, np.asarray(c1), np.asarray(c2)
    return out


def plan_orientations(
    p0: np.ndarray,
    p1: np.ndarray,
    widths: np.ndarray,
    target: BaseGeometry,
    nozzle: Nozzle,
    machine: Machine,
    *,
    options: OrientationOptions = OrientationOptions(),
    previous: float = 0.0,
    prepared_target: BaseGeometry | None = None,
    chained: np.ndarray | None = None,
    interior: np.ndarray | None = None,
    workers: int = 1,
) -> Plan:
    """Choose an orientation for every extruding move of one layer.

    Parameters
    ----------
    p0, p1
        (n, 2) start and end of each move, in print order, mm.
    widths
        (n,) bead width the slicer planned, mm (NaN: no preference).
    target
        The layer target G (shapely).
    nozzle, machine
        What prints it. An XY machine or a round nozzle never turns: the
        only orientation is 0.
    options
        Tolerances and policies (see :class:`OrientationOptions`; ``narrow_beads``,
        ``fold_pieces`` among them).
    previous
        Orientation before the first move, degrees.
    prepared_target
        G already grown by the tolerance and prepared (to share between calls).
    chained
        (n,) True where a move starts where the previous one ended, without
        anything in between: the turn to its orientation may then be made
        *during* it when the footprint turning along the move still fits
        (``Plan.fold``); otherwise the nozzle turns standing still, not
        extruding.
    interior
        (n,) True where the bead's edges are not the part's surface (inner walls, infill:
        :data:`gcode.dialects.INTERIOR_CATEGORIES`): such a move may lay a bead *wider*
        than planned wherever that still fits in the target, so that the nozzle need not
        turn at each change of direction (a turn standing still is a full stop of the
        XY motion on real firmware); narrower than planned costs as everywhere. The
        caller keeps the slicer's volume for it (a wider footprint over the same bead).
        None: every move lays the planned width.
    workers
        Threads the footprint tests are shared out over (the same plan on any number).

    Returns
    -------
    Plan
    """
    ctx = plan_context(p0, p1, widths, target, nozzle, machine, options=options,
                       prepared_target=prepared_target, workers=workers)
    n = len(ctx.p0)
    if interior is not None:
        interior = np.broadcast_to(np.asarray(interior, dtype=bool), (n,))
    turns = machine.turns(nozzle)
    c1 = c2 = None
    if turns:
        angle, c1, c2 = preferred_orientations(ctx.direction, ctx.widths, nozzle, machine,
                                               previous=previous, return_candidates=True)
    else:
        angle = np.zeros(n)
    ok = fp.fits(ctx.target, ctx.pieces, ctx.p0, ctx.p1, angle, scale=ctx.scale,
                 workers=workers)
    pieces: Mapping[int, list[OrientedPiece]] = {}
    rows = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0))
    bad = np.flatnonzero(~ok)
    if bad.size:
        rows, pieces = _search_refused(ctx, angle, (c1, c2), bad, previous=previous,
                                       machine=machine, nozzle=nozzle)
    if turns and n > 1:
        angle = smooth(ctx, angle, bad, c1, c2, previous=previous, machine=machine)
        if machine.covers_period(ctx.per):
            angle = least_turning(angle, rows, c1, c2, ctx, previous, chained,
                                  interior=interior if options.wider_interior else None)
    fold = np.zeros(n, dtype=bool)
    piece_fold = np.zeros(len(rows[0]), dtype=bool)
    if turns and chained is not None and n > 0:
        fold, piece_fold = fold_flags(ctx, angle, rows, np.asarray(chained, bool),
                                      fold_pieces=options.fold_pieces)
    width = np.full(n, np.nan)
    good = ~np.isnan(angle)
    rel = np.mod(angle[good] - ctx.direction[good], 360.0)
    width[good] = np.interp(rel, np.append(ctx.beta, 360.0), np.append(ctx.wtab, ctx.wtab[0]))
    return Plan(angle=angle, width=width, pieces=pieces, fold=fold, piece_rows=rows,
                piece_fold=piece_fold)


def plan_context(p0: np.ndarray, p1: np.ndarray, widths: np.ndarray, target: BaseGeometry,
                 nozzle: Nozzle, machine: Machine, *,
                 options: OrientationOptions = OrientationOptions(),
                 prepared_target: BaseGeometry | None = None,
                 workers: int = 1) -> PlanContext:
    """The :class:`~printability.planning.plan.PlanContext` of :func:`plan_orientations` (its
    parameters of the same names)."""
    p0 = np.asarray(p0, dtype=float).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=float).reshape(-1, 2)
    n = len(p0)
    widths = np.broadcast_to(np.asarray(widths, dtype=float), (n,))
    if prepared_target is None:
        prepared_target = fp.grown_target(target, options.tolerance)
    direction = np.degrees(np.arctan2(p1[:, 1] - p0[:, 1], p1[:, 0] - p0[:, 0]))
    scale = None
    if nozzle.is_round and options.narrow_beads:
        d = 2.0 * nozzle.footprints[0].a
        scale = np.where(np.isfinite(widths), np.minimum(1.0, widths / d), 1.0)
    beta, wtab = width_table(nozzle)
    return PlanContext(p0=p0, p1=p1, direction=direction, widths=widths, scale=scale,
                       target=prepared_target, pieces=fp.convex_pieces(nozzle),
                       per=nozzle.symmetry_period if machine.turns(nozzle) else 360.0,
                       beta=beta, wtab=wtab, options=options,
                       step=options.split_length or max(0.05, nozzle.radius / 4),
                       workers=workers)


def _search_refused(ctx: PlanContext, angle: np.ndarray, picks: tuple, bad: np.ndarray, *,
                    previous: float, machine: Machine, nozzle: Nozzle) -> tuple:
    """Steps 2 and 3 of the module docs for the moves ``bad`` that do not fit at their
    preferred orientation (``picks``: the two laying the planned width per move): ``angle``
    is updated in place (NaN where a move is split or dropped); returns the pieces' rows
    and their :class:`PieceMap`."""
    turns = machine.turns(nozzle)
    cands = candidate_orientations(machine, nozzle, step=ctx.options.search_step) if turns \
        else np.array([0.0])
    # turn least relative to the preferred chain (smooth along curves); the
    # smoothing pass re-chains the orientations the search chose
    prev_bad = np.concatenate([[previous], angle[:-1]])[bad]
    todo = np.arange(bad.size)  # the bad moves the search and the split still take
    exact = None
    if turns:
        todo, exact = _other_width_solution(ctx, angle, picks, bad, prev_bad, cands, machine)
    mv = bad[todo]
    prev_mv = prev_bad[todo]
    sub = ctx.take(mv)
    # A long move that fails at its four cheapest orientations almost always fails at
    # its ends (corners, line ends): it goes straight to the split, which searches the
    # ends at every orientation; short moves are searched at every orientation here.
    long_move = np.hypot(*(sub.p1 - sub.p0).T) > 4 * ctx.step
    # the candidates in order of cost, once for the search and the split (a move's
    # row depends on its direction, width and previous orientation only)
    near, order = cost_order(sub.direction, sub.widths, prev_mv, cands, ctx.beta, ctx.wtab,
                             ctx.per, ctx.options)
    limit = np.where(long_move, 8, len(cands))
    found, best = search_ordered(ctx.target, ctx.pieces, sub.p0, sub.p1, near, order,
                                 sub.scale, limit=limit, workers=ctx.workers)
    angle[mv[found]] = best[found]
    rest = np.flatnonzero(~found)
    if rest.size == 0:
        return (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)), {}
    pm, pa, pb, pp = split_many(sub.take(rest), prev_mv[rest], cands,
                                ordered=(take_rows(near, rest), take_rows(order, rest)),
                                tried=tried_counts(limit[rest], len(cands)),
                                exact=None if exact is None else exact[rest])
    rows = (mv[rest][pm], pa, pb, pp)
    if turns:
        rows = drop_side_pieces(ctx, align_pieces(ctx, rows))
    angle[mv[rest]] = np.nan
    return rows, PieceMap(mv[rest], rows)


def _other_width_solution(ctx: PlanContext, angle: np.ndarray, picks: tuple, bad: np.ndarray,
                          prev_bad: np.ndarray, cands: np.ndarray, machine: Machine) -> tuple:
    """The other orientation laying the planned width, before the grid's (10° apart: they
    miss the width by up to a few hundredths of a mm, and a wider one cannot fit where G is
    just the planned bead): tried on the whole moves ``bad`` (``angle`` updated in place
    where it fits); returns the positions in ``bad`` still to search and, for those, both
    exact orientations (for the split's search for the middle to keep)."""
    c1, c2 = picks
    per = ctx.per
    todo = np.arange(bad.size)
    alt = other_solution(angle[bad], c1[bad], c2[bad], per, machine)
    other = np.flatnonzero(alt != angle[bad])
    if other.size:
        tried = bad[other]
        hit = fp.fits(ctx.target, ctx.pieces, take_rows(ctx.p0, tried),
                      take_rows(ctx.p1, tried), alt[other],
                      scale=None if ctx.scale is None else ctx.scale[tried],
                      workers=ctx.workers)
        angle[bad[other[hit]]] = alt[other[hit]]
        todo = np.setdiff1d(todo, other[hit], assume_unique=True)
    # taken to the grid's range, then unwrapped near the previous orientation as
    # the grid is (_cost_terms): an exact orientation that is a grid one (a turn
    # of 90°, say) gets the same value, so pieces at it join
    e = cands[0] + np.mod(np.column_stack([angle[bad[todo]], alt[todo]]) - cands[0], per)
    return todo, e + per * np.round((prev_bad[todo][:, None] - e) / per)
