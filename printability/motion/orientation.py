"""Choose the nozzle orientation of every extruding move (MMC-safe).

A move from p₀ to p₁ at the constant orientation φ deposits inside the swept
footprint ``[p₀, p₁] ⊕ R(φ)A⁰``. For a convex orifice that is the convex hull
of the footprint placed at both ends; a non-convex polygon is split into
triangles and each is swept. The move is *admissible* at φ when that swept
region lies inside the layer target G grown by ``tolerance`` (equivalently:
the segment lies in the motion restriction P_φ = G ⊖ R(φ)A⁰, up to the
tolerance). Footprints are tested with their *outer* polygonal
approximation, so curved orifices are never under-estimated.
The footprints and that test are :mod:`printability.motion.footprints`.

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
   orientation where it fits (:func:`_align_pieces`);
4. along each path, the admissible orientations (of a few per whole move: those laying
   the planned width, the grid, fixed angles to the motion) whose turns cost least,
   a turn made standing still (larger than ``fold_max``, or not admissible during
   the move) and a reversal costing extra (:func:`~printability.motion.turns.least_turning`);
5. which turns are made during a move or a piece of a split one (``Plan.fold``,
   ``Plan.piece_fold``: :func:`_folds`, with the turning footprint tested in steps of
   at most :data:`_TURN_STEP`, :func:`~printability.motion.turns.turning_fits`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from shapely.geometry.base import BaseGeometry

from printability._arrays import take_rows
from printability.machine import Machine
from printability.motion import footprints as fp
from printability.motion._plan_kernels import (
    chain_nearest,
    merge_pieces,
    smooth_chain,
    width_picks,
)
from printability.motion._search import _cost_order, _search_ordered, _split_many, _tried
from printability.motion.footprints import (
    ConvexPiece,
    convex_pieces,
    fits,
    swept_footprints,
    swept_rings,
)
from printability.motion.turns import least_turning, turning_fits
from printability.nozzle import Nozzle

__all__ = [
    "ConvexPiece",
    "OrientationOptions",
    "OrientedPiece",
    "PieceMap",
    "Plan",
    "candidate_orientations",
    "convex_pieces",
    "fits",
    "piece_rows_of",
    "plan_orientations",
    "swept_footprints",
    "swept_rings",
    "width_table",
]


@dataclass(frozen=True)
class OrientationOptions:
    """Tolerances of the orientation search.

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
        many planned bead widths long are left out (see :func:`_drop_side_pieces`):
        a turn standing still costs more print time than such a fleck is worth.
        0 keeps every piece that fits.
    wider_interior
        Whether the moves :func:`plan_orientations` is told are interior (inner walls,
        infill) may lay a bead wider than planned where it fits, rather than turn at
        every change of direction (False: every move lays the planned width).
    """

    tolerance: float = 1e-3
    quad_segs: int = 16
    search_step: float = 10.0
    width_slack: float = 0.02
    split_length: float | None = None
    fold_max: float = 20.0
    side_piece_widths: float = 1.0
    wider_interior: bool = True


@dataclass(frozen=True)
class OrientedPiece:
    """One printable piece of a move: from ``t0`` to ``t1`` (fractions of the move) at ``angle``."""

    t0: float
    t1: float
    angle: float


class PieceMap(Mapping):
    """Split moves → their printable pieces (:class:`OrientedPiece` lists; empty: dropped).

    A read-only mapping over the pieces held as arrays ``rows = (move, t0, t1, angle)``
    sorted by move (:attr:`Plan.piece_rows`), with ``keys`` the split moves in order. A
    move's list is made when first read: the post-processor's own steps (the rewrite,
    the reports) read the arrays, and making every object up front cost the calibration
    cube about 20 ms (1.5 µs per frozen dataclass, 15 000 pieces).
    """

    __slots__ = ("_made", "_rows", "_span")

    def __init__(self, keys: np.ndarray, rows: tuple) -> None:
        keys = np.asarray(keys, np.int64)
        move = np.asarray(rows[0], np.int64)
        lo = np.searchsorted(move, keys, "left").tolist()
        hi = np.searchsorted(move, keys, "right").tolist()
        self._span = dict(zip(keys.tolist(), zip(lo, hi, strict=True), strict=True))
        self._rows = rows
        self._made: dict[int, list[OrientedPiece]] = {}

    def __getitem__(self, move: int) -> list[OrientedPiece]:
        got = self._made.get(move)
        if got is None:
            lo, hi = self._span[move]
            _, t0, t1, angle = self._rows
            got = list(map(OrientedPiece, t0[lo:hi].tolist(), t1[lo:hi].tolist(),
                           angle[lo:hi].tolist()))
            self._made[move] = got
        return got

    def __contains__(self, move: object) -> bool:
        return move in self._span

    def __iter__(self) -> Iterator[int]:
        return iter(self._span)

    def __len__(self) -> int:
        return len(self._span)

    def __repr__(self) -> str:
        return f"PieceMap({len(self)} moves, {len(self._rows[0])} pieces)"


@dataclass(frozen=True, eq=False)
class Plan:
    """The orientation of every move of one layer.

    Attributes
    ----------
    angle
        Orientation per move, degrees (NaN where the whole move is dropped or split).
    pieces
        For split moves (index → printable pieces, possibly empty = dropped): a dict, or
        the planner's :class:`PieceMap`.
    width
        Bead width laid at the chosen orientation, mm (NaN if dropped/split).
    fold
        (n,) True where the turn from the previous move's orientation (its last piece's
        when it is split) is made during the move (checked with the turning footprint).
    piece_rows
        The pieces of ``pieces`` as arrays ``(move, t0, t1, angle)``, by move and then
        as listed (empty lists have no row); built from ``pieces`` when not given.
    piece_fold
        Per row of ``piece_rows``, True where the turn into the piece (from the previous
        piece of its move, or from the previous move for its first piece) is made during
        the piece (checked with the turning footprint); None: never.
    """

    angle: np.ndarray
    width: np.ndarray
    pieces: Mapping[int, list[OrientedPiece]] = field(default_factory=dict)
    fold: np.ndarray | None = None
    piece_rows: tuple | None = None
    piece_fold: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.piece_rows is None:
            object.__setattr__(self, "piece_rows", piece_rows_of(self.pieces))

    @property
    def split_moves(self) -> int:
        return sum(1 for p in self.pieces.values() if p)

    @property
    def dropped_moves(self) -> int:
        return sum(1 for p in self.pieces.values() if not p)

    def dropped_length(self, lengths: np.ndarray) -> float:
        """Length of the dropped parts of the moves, mm."""
        total = 0.0
        for i, pieces in self.pieces.items():
            kept = sum(p.t1 - p.t0 for p in pieces)
            total += float(lengths[i]) * max(0.0, 1.0 - kept)
        return total


def piece_rows_of(seg_pieces: Mapping) -> tuple:
    """The pieces of a ``{move: [OrientedPiece, …]}`` dict as arrays ``(move, t0, t1,
    angle)``, by move and then as listed (dropped moves, with no piece, have no row)."""
    keys = sorted(seg_pieces)
    n = [len(seg_pieces[k]) for k in keys]
    flat = [p for k in keys for p in seg_pieces[k]]
    return (np.repeat(np.asarray(keys, np.int64), n), np.array([p.t0 for p in flat], float),
            np.array([p.t1 for p in flat], float), np.array([p.angle for p in flat], float))


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


def _reachable(phi: np.ndarray, machine: Machine, period: float) -> np.ndarray:
    """Whether some equivalent of each orientation lies within the axis limits."""
    if not machine.has_rotary:
        return np.isclose(np.mod(phi + 1e-9, period or 360.0), 1e-9, atol=1e-6)
    lo, hi = machine.angle_min, machine.angle_max
    if hi - lo >= period - 1e-9:
        return np.ones(phi.shape, dtype=bool)
    k = np.ceil((lo - phi) / period - 1e-12)
    return phi + k * period <= hi + 1e-9


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
    grown by a fraction of τ (τ = 1 µm; :data:`~printability.motion.beadunion.SIDE`):
    every such move was refused there and laid at a narrower grid orientation instead.
    Here the width is bisected between ``b`` and the neighbouring entry on the other
    side of ``w``, keeping the end that is not wider
    (:meth:`~printability.nozzle.Nozzle.bead_widths`). Where neither neighbour lies
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
            if reach and not _reachable(np.array([c]), machine, per)[0]:
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
    narrow_beads: bool = False,
    fold_pieces: bool = True,
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
        Tolerances (see :class:`OrientationOptions`).
    previous
        Orientation before the first move, degrees.
    prepared_target
        G already grown by the tolerance and prepared (to share between calls).
    narrow_beads
        A round nozzle lays the planned width where the plan is narrower than
        the orifice (the slicer's own model of *its* nozzle: bridges and gap
        fill are under-extruded on purpose), so its footprint there is the
        disk of the planned width. Only true for the nozzle the file was
        sliced for (or a smaller one); otherwise the whole orifice counts.
    chained
        (n,) True where a move starts where the previous one ended, without
        anything in between: the turn to its orientation may then be made
        *during* it when the footprint turning along the move still fits
        (``Plan.fold``); otherwise the nozzle turns standing still, not
        extruding.
    fold_pieces
        Whether the turns into the pieces of split moves may be made during them too
        (``Plan.piece_fold``; with ``chained`` given).
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
    p0 = np.asarray(p0, dtype=float).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=float).reshape(-1, 2)
    n = len(p0)
    widths = np.broadcast_to(np.asarray(widths, dtype=float), (n,))
    if interior is not None:
        interior = np.broadcast_to(np.asarray(interior, dtype=bool), (n,))
    if prepared_target is None:
        prepared_target = fp.grown_target(target, options.tolerance)
    pieces = fp.convex_pieces(nozzle)
    period = nozzle.symmetry_period
    turns = machine.turns(nozzle)
    per = period if turns else 360.0
    direction = np.degrees(np.arctan2(p1[:, 1] - p0[:, 1], p1[:, 0] - p0[:, 0]))
    scale = None
    if nozzle.is_round and narrow_beads:
        d = 2.0 * nozzle.footprints[0].a
        scale = np.where(np.isfinite(widths), np.minimum(1.0, widths / d), 1.0)
    if turns:
        angle, c1, c2 = preferred_orientations(direction, widths, nozzle, machine,
                                               previous=previous, return_candidates=True)
    else:
        angle = np.zeros(n)

    ok = fp.fits(prepared_target, pieces, p0, p1, angle, scale=scale, workers=workers)
    result_pieces: Mapping[int, list[OrientedPiece]] = {}
    rows = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0))
    bad = np.flatnonzero(~ok)
    beta, wtab = width_table(nozzle)
    if bad.size:
        cands = candidate_orientations(machine, nozzle, step=options.search_step) if turns \
            else np.array([0.0])
        # turn least relative to the preferred chain (smooth along curves); the
        # smoothing pass below re-chains the orientations the search chose
        prev_bad = np.concatenate([[previous], angle[:-1]])[bad]
        todo = np.arange(bad.size)  # the bad moves the search and the split still take
        exact = None
        if turns:
            # The other orientation laying the planned width, before the grid's (10° apart:
            # they miss the width by up to a few hundredths of a mm, and a wider one
            # cannot fit where G is just the planned bead): first on the whole move, then
            # with the chain's in the split's search for the middle to keep.
            alt = _other_solution(angle[bad], c1[bad], c2[bad], per, machine)
            other = np.flatnonzero(alt != angle[bad])
            if other.size:
                tried = bad[other]
                hit = fp.fits(prepared_target, pieces, take_rows(p0, tried), take_rows(p1, tried),
                              alt[other], scale=None if scale is None else scale[tried],
                              workers=workers)
                angle[bad[other[hit]]] = alt[other[hit]]
                todo = np.setdiff1d(todo, other[hit], assume_unique=True)
            # taken to the grid's range, then unwrapped near the previous orientation as
            # the grid is (_cost_terms): an exact orientation that is a grid one (a turn
            # of 90°, say) gets the same value, so pieces at it join
            e = cands[0] + np.mod(np.column_stack([angle[bad[todo]], alt[todo]]) - cands[0],
                                  per)
            exact = e + per * np.round((prev_bad[todo][:, None] - e) / per)
        mv = bad[todo]
        prev_mv = prev_bad[todo]
        sc = None if scale is None else scale[mv]
        # A long move that fails at its four cheapest orientations almost always fails at
        # its ends (corners, line ends): it goes straight to the split, which searches the
        # ends at every orientation; short moves are searched at every orientation here.
        step = options.split_length or max(0.05, nozzle.radius / 4)
        p0_mv, p1_mv = take_rows(p0, mv), take_rows(p1, mv)
        long_move = np.hypot(*(p1_mv - p0_mv).T) > 4 * step
        # the candidates in order of cost, once for the search and the split (a move's
        # row depends on its direction, width and previous orientation only)
        near, order = _cost_order(direction[mv], widths[mv], prev_mv, cands, beta, wtab,
                                  per, options)
        limit = np.where(long_move, 8, len(cands))
        found, best = _search_ordered(prepared_target, pieces, p0_mv, p1_mv, near, order,
                                      sc, limit=limit, workers=workers)
        angle[mv[found]] = best[found]
        rest = np.flatnonzero(~found)
        if rest.size:
            pm, pa, pb, pp = _split_many(
                prepared_target, pieces, take_rows(p0_mv, rest), take_rows(p1_mv, rest),
                direction[mv[rest]], widths[mv[rest]], prev_mv[rest], cands, beta, wtab, per,
                nozzle, options, None if sc is None else sc[rest],
                ordered=(take_rows(near, rest), take_rows(order, rest)),
                tried=_tried(limit[rest], len(cands)),
                exact=None if exact is None else exact[rest], workers=workers)
            rows = (mv[rest][pm], pa, pb, pp)
            if turns:
                rows = _align_pieces(rows, direction, widths, per, prepared_target, pieces,
                                     p0, p1, beta, wtab, options, workers=workers)
                rows = _drop_side_pieces(rows, widths, p0, p1, per, options)
            result_pieces = PieceMap(mv[rest], rows)
            angle[mv[rest]] = np.nan
    if turns and n > 1:
        angle = _smooth(angle, bad, c1, c2, per, previous, prepared_target, pieces, p0, p1,
                        scale, machine, workers=workers)
        if machine.covers_period(per):
            angle = least_turning(angle, rows, c1, c2, direction, widths, per, previous,
                                   prepared_target, pieces, p0, p1, scale, chained, beta,
                                   wtab, options,
                                   interior=interior if options.wider_interior else None,
                                   workers=workers)
    fold = np.zeros(n, dtype=bool)
    piece_fold = np.zeros(len(rows[0]), dtype=bool)
    if turns and chained is not None and n > 0:
        fold, piece_fold = _folds(angle, rows, np.asarray(chained, bool), per, options,
                                  prepared_target, pieces, p0, p1, fold_pieces,
                                  workers=workers)
    width = np.full(n, np.nan)
    good = ~np.isnan(angle)
    rel = np.mod(angle[good] - direction[good], 360.0)
    width[good] = np.interp(rel, np.append(beta, 360.0), np.append(wtab, wtab[0]))
    return Plan(angle=angle, width=width, pieces=result_pieces, fold=fold, piece_rows=rows,
                piece_fold=piece_fold)


def _folds(angle, rows, chained, per, options, target, pieces, p0, p1, fold_pieces, *,
           workers=1):
    """Which turns are made while moving: ``Plan.fold`` (per move) and ``Plan.piece_fold``
    (per piece row).

    A turn of at most ``fold_max`` into a whole move chained to the previous one (whose
    orientation is its own, or its last piece's when it is split) is made during the move
    where the footprint turning along it fits; the same for a piece of a split move, from
    the previous piece of the move or, for its first piece, from the previous move (when
    chained; ``fold_pieces`` False: never, as where F would not be the XY feed). The test
    is :func:`~printability.motion.turns.turning_fits`, on the piece's own stretch of the
    move: what it deposits while turning stays inside the grown target, as every other
    footprint.
    """
    n = len(angle)
    pm, pt0, pt1, pa = rows
    pm = np.asarray(pm, np.int64)
    npc = pm.size
    # each move's last orientation (NaN: dropped)
    end = np.asarray(angle, float).copy()
    first = np.zeros(0, bool)
    if npc:
        first = np.ones(npc, bool)
        first[1:] = pm[1:] != pm[:-1]
        last = np.append(pm[1:] != pm[:-1], True)
        end[pm[last]] = pa[last]
    fold = np.zeros(n, dtype=bool)
    piece_fold = np.zeros(npc, dtype=bool)
    whole = np.isfinite(angle)
    # whole moves: from the previous move's end (the raw difference after a whole move, as
    # the chain unwrapped them; the nearest equivalent after a split one)
    prev_a = np.concatenate([[np.nan], end[:-1]])
    after_whole = np.concatenate([[False], whole[:-1]])
    a_end = np.where(after_whole, angle, angle + per * np.round((prev_a - angle) / per))
    with np.errstate(invalid="ignore"):
        step = np.abs(a_end - prev_a)
        cand = np.flatnonzero(chained & whole & np.isfinite(step) & (step > 1e-9)
                              & (step <= options.fold_max))
    # pieces: from the previous piece of the move, or the previous move's end
    q_prev = np.full(npc, np.nan)
    q_ok = np.zeros(npc, bool)
    if npc and fold_pieces:
        q_prev[~first] = pa[:-1][~first[1:]]
        q_ok[~first] = True
        fm = pm[first]
        has_prev = fm > 0
        q_prev[np.flatnonzero(first)[has_prev]] = end[fm[has_prev] - 1]
        q_ok[np.flatnonzero(first)[has_prev]] = chained[fm[has_prev]]
    q_end = pa + per * np.round((q_prev - pa) / per) if npc else pa
    with np.errstate(invalid="ignore"):
        q_step = np.abs(q_end - q_prev)
        q_cand = np.flatnonzero(q_ok & np.isfinite(q_step) & (q_step > 1e-9)
                                & (q_step <= options.fold_max))
    m = q_cand.size
    if cand.size + m == 0:
        return fold, piece_fold
    mv = pm[q_cand]
    d = take_rows(p1, mv) - take_rows(p0, mv)
    a0 = take_rows(p0, mv) + pt0[q_cand][:, None] * d
    a1 = take_rows(p0, mv) + pt1[q_cand][:, None] * d
    ok = turning_fits(target, pieces, np.concatenate([take_rows(p0, cand), a0]),
                       np.concatenate([take_rows(p1, cand), a1]),
                       np.concatenate([prev_a[cand], q_prev[q_cand]]),
                       np.concatenate([a_end[cand], q_end[q_cand]]), workers=workers)
    fold[cand] = ok[:cand.size]
    piece_fold[q_cand] = ok[cand.size:]
    return fold, piece_fold


def _longest_piece(pm: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Per piece row (rows sorted by move ``pm``), the row of its move's longest piece
    (the first of equals). O(rows)."""
    npc = len(pm)
    lo = np.flatnonzero(np.concatenate([[True], pm[1:] != pm[:-1]]))
    best = lo + np.array([int(np.argmax(span[a:b])) for a, b in
                          zip(lo.tolist(), [*lo[1:].tolist(), npc], strict=True)], np.int64)
    return np.repeat(best, np.diff(np.append(lo, npc)))


def _align_pieces(rows, direction, widths, per, target, pieces, p0, p1, beta, wtab, options, *,
                  workers=1):
    """The pieces of each split move next to its longest one take that one's orientation
    where it fits there and lays a width no further from the plan (``width_slack``) than
    their own: no turn between them then (and contiguous ones are joined into one).

    The split searches each stretch on its own, cheapest first, and the short pieces next
    to a corner end up at a grid orientation a few degrees from the long piece's.
    """
    pm, t0, t1, pa = rows
    npc = len(pm)
    if npc < 2:
        return rows
    anchor = _longest_piece(pm, t1 - t0)
    r = np.arange(npc)
    near = (np.abs(r - anchor) == 1)
    target_a = pa[anchor]
    diff = np.abs((pa - target_a + per / 2) % per - per / 2)
    cand = np.flatnonzero(near & (diff > 1e-9))
    if cand.size == 0:
        return rows
    table_b = np.append(beta, 360.0)
    table_w = np.append(wtab, wtab[0])
    m = pm[cand]
    w_plan = widths[m]

    def werr(phi):
        w = np.interp(np.mod(phi - direction[m], 360.0), table_b, table_w)
        return np.where(np.isnan(w_plan), 0.0, np.abs(w - np.nan_to_num(w_plan)))

    ok_w = werr(target_a[cand]) <= werr(pa[cand]) + options.width_slack
    cand = cand[ok_w]
    if cand.size == 0:
        return rows
    m = pm[cand]
    d = p1[m] - p0[m]
    a = p0[m] + t0[cand][:, None] * d
    b = p0[m] + t1[cand][:, None] * d
    ok = fp.fits(target, pieces, a, b, target_a[cand], workers=workers)
    if not ok.any():
        return rows
    pa = pa.copy()
    pa[cand[ok]] = target_a[cand[ok]]
    return merge_pieces(pm, t0, t1, pa)


def _drop_side_pieces(rows, widths, p0, p1, per, options):
    """Leave out the short pieces of split moves that need a turn of their own.

    At a convex corner of an outer wall an elongated orifice laying the planned width
    pokes out of the part for a few tenths of a millimetre on either side; the split then
    finds, for those ends, other orientations (narrower, along the motion) that still fit,
    and the nozzle turns there and back: two or three turns per corner, each a full stop
    of the XY motion on real firmware, for a fleck of material (the calibration cube on a
    360 °/s axis: 0.6 s per corner, 40 % more print time). A piece other than its move's
    longest, at another orientation than that one, and at most
    ``options.side_piece_widths`` planned bead widths long is dropped (its length is
    reported as lost, like every dropped length); 0 keeps them all.
    """
    k = options.side_piece_widths
    pm, t0, t1, pa = rows
    npc = len(pm)
    if k <= 0 or npc < 2:
        return rows
    span = t1 - t0
    anchor = _longest_piece(pm, span)
    length = span * np.hypot(*(p1[pm] - p0[pm]).T)
    w = np.asarray(widths, dtype=float)[pm]
    limit = k * np.where(np.isfinite(w), w, 0.0)
    turned = np.abs((pa - pa[anchor] + per / 2) % per - per / 2) > 1e-6
    keep = ~(turned & (length <= limit) & (np.arange(npc) != anchor))
    if keep.all():
        return rows
    return (pm[keep], t0[keep], t1[keep], pa[keep])


def _smooth(angle, searched, c1, c2, per, previous, target, pieces, p0, p1, scale, machine, *,
            workers=1):
    """Second pass: turn least given the orientations the search replaced.

    The preferred orientations were chained assuming every move fits; where
    the search replaced one, the next moves may now be nearer to the other
    solution of the same width. Proposals are re-tested together and kept
    only where they fit; an equivalent orientation (a multiple of the period
    away) needs no test.
    """
    n = len(angle)
    is_searched = np.zeros(n, dtype=bool)
    is_searched[np.asarray(searched, dtype=np.int64)] = True
    reach = machine.has_rotary and not machine.covers_period(per)
    prop = smooth_chain(np.asarray(angle, dtype=float), np.asarray(c1, dtype=float),
                        np.asarray(c2, dtype=float), is_searched, bool(reach), float(per),
                        float(previous))
    diff = np.abs((prop - angle + per / 2) % per - per / 2)
    test = np.flatnonzero(np.isfinite(prop) & (diff > 1e-6))
    out = np.where(np.isfinite(prop), prop, angle)
    if test.size:
        ok = fp.fits(target, pieces, take_rows(p0, test), take_rows(p1, test), prop[test],
                     scale=None if scale is None else scale[test], workers=workers)
        keep = test[~ok]
        # a rejected proposal keeps its old orientation, unwrapped near its neighbour
        out[keep] = angle[keep]
    return out


def _other_solution(pick, c1, c2, per, machine):
    """Per move, the orientation laying the planned width that the chain did not pick
    (``c1`` or ``c2``, unwrapped near ``pick``); ``pick`` itself where there is one only
    or the other is out of the axis' reach."""
    d1 = np.abs(np.mod(pick - c1 + per / 2, per) - per / 2)
    d2 = np.abs(np.mod(pick - c2 + per / 2, per) - per / 2)
    raw = np.where(d1 <= d2, c2, c1)
    alt = raw + per * np.round((pick - raw) / per)
    same = np.minimum(d1, d2) > 1e-9  # the pick is neither (out of reach: clipped)
    same |= np.abs(np.mod(alt - pick + per / 2, per) - per / 2) < 1e-9
    if machine.has_rotary and not machine.covers_period(per):
        same |= ~_reachable(alt, machine, per)
    return np.where(same, pick, alt)
