"""Ranking candidate nozzles: least material lost first, then the fastest build.

docs/design.md §2: ranking = ascending λ(G \\ S) (area for one layer, volume over
layers), ties broken by an estimated build time.

Certified ranks
---------------
Every engine reports, besides its estimate of the lost amount, an interval
[lo, hi] certified to contain the exact value. The rows are listed by
estimate, but the *rank a nozzle certainly has* is an interval too: nozzle i
is certainly better than j when hi_i < lo_j (its worst case loses less than
j's best case), so i's rank lies in

    [1 + #{j : hi_j < lo_i},  n − #{j : lo_j > hi_i}]

(:func:`certified_ranks`). When two nozzles' intervals overlap they are tied
within the certified bounds: the ranking says so (``rank_range`` with two
different ends, ``tied_with``) rather than claiming the order of their
estimates; :func:`printability.analysis.analyze` can refine just those
nozzles until their intervals separate.

Build-time model
----------------
The time to fill the as-built region S with beads laid side by side at a
constant feed:

    t = Σ_layers λ(S_layer) / (w · v)      [mm² / (mm · mm/s) = s]

with v the deposition speed (``speed``, mm/s) and w the bead width of the
nozzle. On a machine with a rotary axis the motion planner turns an
asymmetric nozzle to lay its widest bead where it fits (docs/design.md §3), so
w = ``max_width``; on an XY machine the nozzle cannot turn and paths run in
every direction, so w is the mean bead width over directions (for a circle
both are the diameter). Each orifice of a multi-orifice head lays its own
bead, so their widths add. The model ignores travel, acceleration, layer
changes and the narrower beads of thin features: it is meant to order
nozzles that lose the same material, not to predict a print time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from printability.errors import InputError
from printability.mmc.result import MMCResult
from printability.model.nozzle import Nozzle

__all__ = ["DEFAULT_SPEED", "RankRow", "Totals", "bead_width_for_time", "certified_ranks",
           "rank", "rank_label", "rank_order", "ties", "totals", "uses_volume"]

DEFAULT_SPEED = 40.0
"""Deposition speed of the build-time model, mm/s (a typical perimeter/infill speed)."""


@dataclass(frozen=True)
class RankRow:
    """One nozzle's place in a ranking.

    Attributes
    ----------
    rank
        1 = best (least lost, then fastest).
    spec
        The nozzle SPEC.
    nozzle
        The nozzle.
    machine
        Name of the machine the results were computed for.
    layers
        Number of layer results aggregated.
    unit
        ``"mm²"`` for one layer or summed areas, ``"mm³"`` when layer heights were given.
    target, as_built, lost
        λ(G), λ(S), λ(G \\ S), summed over layers (times the layer heights for volumes).
    lost_bounds
        (lo, hi) summed the same way: the certified interval of every engine.
    lost_fraction
        lost / target.
    bead_width
        w of the build-time model, mm.
    build_time
        Estimated time to deposit S, s.
    components
        Largest number of components of P over the layers.
    rank_range
        (best, worst): the ranks the certified bounds allow (:func:`certified_ranks`);
        equal ends when the rank is certain.
    tied_with
        SPECs of the nozzles whose certified interval overlaps this one's.
    """

    rank: int
    spec: str
    nozzle: Nozzle
    machine: str
    layers: int
    unit: str
    target: float
    as_built: float
    lost: float
    lost_bounds: tuple[float, float]
    lost_fraction: float
    bead_width: float
    build_time: float
    components: int
    rank_range: tuple[int, int] = (0, 0)
    tied_with: tuple[str, ...] = ()

    @property
    def rank_certain(self) -> bool:
        """Whether the certified bounds fix this rank (no other interval overlaps)."""
        return self.rank_range[0] == self.rank_range[1]


class _LayerAreas(Protocol):
    """One layer's figures, as :class:`printability.analysis.LayerOutcome` holds them."""

    height: float
    target_area: float
    lost_area: float
    lost_area_bounds: tuple[float, float]


@dataclass(frozen=True)
class Totals:
    """What a nozzle loses over a part, in one unit: the figures every table shows.

    Attributes
    ----------
    quantity
        ``"area"`` (mm², one layer, or layers without a height: areas summed) or
        ``"volume"`` (mm³: each layer's area times its height, summed).
    unit
        ``"mm²"`` or ``"mm³"``.
    target, lost
        λ(G) and λ(G \\ S) in that unit (the engine's best estimate of the loss).
    lost_bounds
        The certified interval (lo, hi) of ``lost``, in the same unit.
    """

    quantity: str
    unit: str
    target: float
    lost: float
    lost_bounds: tuple[float, float]

    @property
    def lost_fraction(self) -> float:
        """lost / target (0 for an empty target)."""
        return self.lost / self.target if self.target > 0 else 0.0


def uses_volume(heights: Sequence[float]) -> bool:
    """Whether a part's totals are volumes: several layers, each with a height.

    One layer is reported as an area, and so are layers without a height (drawings,
    maps), whose volume would be zero.
    """
    return len(heights) > 1 and all(h > 0 for h in heights)


def totals(layers: Sequence[_LayerAreas], *, volume: bool | None = None) -> Totals:
    """Sum one nozzle's per-layer figures in the part's unit.

    Parameters
    ----------
    layers
        The nozzle's layers (each with ``height``, ``target_area``, ``lost_area``,
        ``lost_area_bounds``).
    volume
        Volumes (area × height) or areas; None chooses with :func:`uses_volume`.

    Returns
    -------
    Totals
        Target, lost and the lost bounds, all in one unit.
    """
    if volume is None:
        volume = uses_volume([o.height for o in layers])
    w = [o.height if volume else 1.0 for o in layers]
    return Totals(
        quantity="volume" if volume else "area", unit="mm³" if volume else "mm²",
        target=float(sum(o.target_area * k for o, k in zip(layers, w, strict=True))),
        lost=float(sum(o.lost_area * k for o, k in zip(layers, w, strict=True))),
        lost_bounds=(float(sum(o.lost_area_bounds[0] * k for o, k in zip(layers, w, strict=True))),
                     float(sum(o.lost_area_bounds[1] * k for o, k in zip(layers, w, strict=True)))),
    )


def bead_width_for_time(nozzle: Nozzle, *, rotary: bool) -> float:
    """The bead width w of the build-time model (module docstring), mm."""
    total = 0.0
    for f in nozzle.footprints:
        one = Nozzle(nozzle.spec, (f,), nozzle.mount_angle)
        if rotary:
            total += one.max_width
        else:
            total += float(np.mean([one.bead_width(d) for d in np.arange(0.0, 180.0, 1.0)]))
    return total


def _layers_of(entry: MMCResult | Sequence[MMCResult], i: int) -> list[MMCResult]:
    layers = [entry] if isinstance(entry, MMCResult) else list(entry)
    if not layers:
        raise InputError(f"ranking: entry {i + 1} has no layer results")
    for r in layers:
        if not isinstance(r, MMCResult):
            raise InputError(f"ranking: entry {i + 1} holds a {type(r).__name__}, expected "
                             "MMCResult objects (one per layer)")
    specs = {r.nozzle.spec for r in layers}
    if len(specs) > 1:
        raise InputError(f"ranking: entry {i + 1} mixes nozzles {sorted(specs)}; give one list "
                         "of layer results per nozzle")
    return layers


def certified_ranks(bounds: Sequence[tuple[float, float]]) -> list[tuple[int, int]]:
    """The ranks each candidate can take given only certified intervals of what it loses.

    Parameters
    ----------
    bounds
        (lo, hi) per candidate, in one unit, each certified to contain the exact value.

    Returns
    -------
    list of (best, worst)
        Candidate i is certainly behind j when hi_j < lo_i and certainly ahead when
        hi_i < lo_j; it can take any rank between 1 + (number certainly ahead) and n −
        (number certainly behind). Intervals that merely touch (hi_j == lo_i) do not
        separate: the exact values might be equal. Cost O(n²).
    """
    n = len(bounds)
    out = []
    for lo_i, hi_i in bounds:
        ahead = sum(1 for lo_j, hi_j in bounds if hi_j < lo_i)
        behind = sum(1 for lo_j, hi_j in bounds if lo_j > hi_i)
        out.append((1 + ahead, n - behind))
    return out


def ties(bounds: Sequence[tuple[float, float]]) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, whose certified intervals overlap (or touch): not separable."""
    return [(i, j) for i in range(len(bounds)) for j in range(i + 1, len(bounds))
            if bounds[j][0] <= bounds[i][1] and bounds[i][0] <= bounds[j][1]]


def rank_label(rank_range: tuple[int, int]) -> str:
    """``"2"`` for a certain rank, ``"1–3"`` when the certified bounds allow ranks 1 to 3."""
    best, worst = rank_range
    return str(best) if best == worst else f"{best}–{worst}"


def rank_order(
    lost: Sequence[float],
    build_time: Sequence[float],
    *,
    tie_tolerance: float = 1e-6,
) -> list[int]:
    """Indices of the candidates, best first: least lost, near-ties by build time.

    Lost amounts closer than ``tie_tolerance`` plus a relative 10⁻⁹ form a
    run that is ordered by build time; equal times keep the input order.
    """
    order = sorted(range(len(lost)), key=lambda i: lost[i])
    ranked: list[int] = []
    run = order[:1]
    for i in order[1:]:
        prev, cur = lost[run[-1]], lost[i]
        if cur - prev <= tie_tolerance + 1e-9 * max(abs(cur), abs(prev)):
            run.append(i)
        else:
            ranked.extend(sorted(run, key=lambda j: (build_time[j], j)))
            run = [i]
    ranked.extend(sorted(run, key=lambda j: (build_time[j], j)))
    return ranked


def rank(
    results: Sequence[MMCResult | Sequence[MMCResult]],
    *,
    heights: Sequence[float] | None = None,
    speed: float = DEFAULT_SPEED,
    tie_tolerance: float = 1e-6,
) -> tuple[RankRow, ...]:
    """Order nozzles by lost area (or volume), ties broken by estimated build time.

    Parameters
    ----------
    results
        One entry per nozzle: an :class:`MMCResult` (one layer) or a sequence
        of them (that nozzle's layers, bottom to top).
    heights
        Layer thicknesses, mm, one per layer (every entry must have that
        many layers). When given, areas become volumes (mm³); otherwise
        areas are summed over layers (mm²).
    speed
        Deposition speed v of the build-time model, mm/s.
    tie_tolerance
        Lost amounts closer than this (mm² or mm³), plus a relative 10⁻⁹,
        are a tie and are ordered by build time.

    Returns
    -------
    tuple of RankRow
        Best first (by estimate); ``rank`` numbers 1, 2, ...; equal lost and time
        keep the order of ``results``. ``rank_range`` and ``tied_with`` say which
        of these places the certified bounds actually establish (module docstring).

    Raises
    ------
    InputError
        No results, an empty entry, an entry mixing nozzles, heights of the
        wrong length or not positive, a speed that is not positive.
    """
    if not results:
        raise InputError("ranking: no nozzle results to rank")
    if not (speed > 0 and math.isfinite(speed)):
        raise InputError(f"ranking: speed must be a positive number of mm/s; got {speed!r}")
    if tie_tolerance < 0:
        raise InputError(f"ranking: tie_tolerance must be ≥ 0; got {tie_tolerance!r}")
    entries = [_layers_of(e, i) for i, e in enumerate(results)]
    if heights is not None:
        h = np.asarray(heights, dtype=float)
        if h.ndim != 1 or not np.all(np.isfinite(h)) or np.any(h <= 0):
            raise InputError("ranking: heights must be positive layer thicknesses in mm")
        for i, layers in enumerate(entries):
            if len(layers) != len(h):
                raise InputError(f"ranking: entry {i + 1} has {len(layers)} layers but "
                                 f"{len(h)} heights were given")
    unsorted = []
    for layers in entries:
        w_h = np.asarray(heights, float) if heights is not None else np.ones(len(layers))
        noz = layers[0].nozzle
        rotary = layers[0].machine.has_rotary and not noz.is_round
        w = bead_width_for_time(noz, rotary=rotary)
        target = float(sum(r.target_area * k for r, k in zip(layers, w_h, strict=True)))
        built = float(sum(r.as_built_area * k for r, k in zip(layers, w_h, strict=True)))
        lost = float(sum(r.lost_area * k for r, k in zip(layers, w_h, strict=True)))
        lo = float(sum(r.lost_area_bounds[0] * k for r, k in zip(layers, w_h, strict=True)))
        hi = float(sum(r.lost_area_bounds[1] * k for r, k in zip(layers, w_h, strict=True)))
        area_built = float(sum(r.as_built_area for r in layers))
        unsorted.append(dict(
            spec=noz.spec, nozzle=noz, machine=layers[0].machine.name, layers=len(layers),
            unit="mm³" if heights is not None else "mm²",
            target=target, as_built=built, lost=lost, lost_bounds=(lo, hi),
            lost_fraction=lost / target if target > 0 else 0.0,
            bead_width=w, build_time=area_built / (w * speed),
            components=max(r.components.count for r in layers),
        ))
    ranked = rank_order([u["lost"] for u in unsorted], [u["build_time"] for u in unsorted],
                        tie_tolerance=tie_tolerance)
    ranges = certified_ranks([u["lost_bounds"] for u in unsorted])
    tied: dict[int, list[str]] = {i: [] for i in range(len(unsorted))}
    for i, j in ties([u["lost_bounds"] for u in unsorted]):
        tied[i].append(unsorted[j]["spec"])
        tied[j].append(unsorted[i]["spec"])
    return tuple(RankRow(rank=n + 1, **unsorted[i], rank_range=ranges[i],
                         tied_with=tuple(tied[i])) for n, i in enumerate(ranked))
