"""The orientation planner's records: what it plans with (:class:`PlanContext`) and what it
plans (:class:`Plan`, the pieces of split moves as :class:`OrientedPiece` rows and a
:class:`PieceMap` over them).

Lengths in mm, angles in degrees, positions along a move as fractions of it.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from shapely.geometry.base import BaseGeometry

from printability.base.arrays import take_rows
from printability.model.shapes import Footprint

if TYPE_CHECKING:
    from printability.planning.orientation import OrientationOptions

__all__ = ["OrientedPiece", "PieceMap", "Plan", "PlanContext", "piece_rows_of"]


@dataclass(frozen=True, eq=False)
class PlanContext:
    """One layer's moves and what the planner's passes test and rank them with.

    Attributes
    ----------
    p0, p1
        (n, 2) start and end of each move, mm.
    direction
        (n,) direction of each move, degrees.
    widths
        (n,) planned bead widths, mm (NaN: no preference).
    scale
        (n,) footprint scale per move (a round nozzle laying a narrower bead), or None.
    target
        G grown by the tolerance, prepared (or a bead union).
    pieces
        The nozzle's convex pieces.
    per
        The period of the orientations, degrees (360 where the nozzle does not turn).
    beta, wtab
        The bead width per orientation relative to the motion (the width table).
    options
        The planner's options.
    step
        The split's resolution, mm.
    workers
        Threads the footprint tests run on.
    """

    p0: np.ndarray
    p1: np.ndarray
    direction: np.ndarray
    widths: np.ndarray
    scale: np.ndarray | None
    target: BaseGeometry
    pieces: Sequence[Footprint]
    per: float
    beta: np.ndarray
    wtab: np.ndarray
    options: OrientationOptions
    step: float
    workers: int = 1

    def take(self, idx: np.ndarray) -> PlanContext:
        """The same context for the moves ``idx`` only."""
        return replace(self, p0=take_rows(self.p0, idx), p1=take_rows(self.p1, idx),
                       direction=self.direction[idx], widths=self.widths[idx],
                       scale=None if self.scale is None else self.scale[idx])


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
