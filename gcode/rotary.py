"""Rotary-axis arithmetic for G-code output: unwrapping, arcs, beads and feed rates.

Plain functions on plain numbers (no geometry engine), shared by the writer,
the post-processor and the generator.

Conventions (docs/design.md §3)
--------------------------
* Angles are in degrees, positive counter-clockwise about +Z. The rotary
  coordinate written to the file is *unwrapped*: each new value is the
  representative of the wanted orientation that is nearest to the previous
  value (shortest signed step), so the axis never spins the long way round.
* A nozzle whose outline repeats after ``period`` degrees (180 for an ellipse
  or a rectangle, 90 for a square) may be turned to any ``φ + k·period``:
  the writer picks the one that turns least.
* Bead cross-section: by default the *Slic3r / PrusaSlicer* model, a
  rectangle with semicircular ends, area ``h·(w − h) + π·h²/4`` for a bead of
  width ``w`` and height ``h`` (``Flow::mm3_per_mm`` for non-bridge extrusions);
  ``"rectangle"`` (area ``w·h``, CuraEngine's model) is the alternative.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "BEAD_MODELS",
    "arc_points",
    "bead_area",
    "e_per_mm",
    "feed_for_move",
    "nearest_equivalent",
    "unwrap_sequence",
    "width_from_e",
]

BEAD_MODELS = ("rounded", "rectangle")


def nearest_equivalent(
    target: float,
    previous: float,
    *,
    period: float = 360.0,
    lo: float = -math.inf,
    hi: float = math.inf,
) -> float | None:
    """The value ``target + k·period`` nearest to ``previous`` within ``[lo, hi]``.

    Parameters
    ----------
    target
        Wanted orientation, degrees (any representative).
    previous
        Current axis coordinate, degrees (already unwrapped).
    period
        Symmetry period of the nozzle, degrees (360 for no symmetry).
    lo, hi
        Travel limits of the axis, degrees; infinite for a slip-ring head.

    Returns
    -------
    float or None
        The unwrapped coordinate, or None when no representative lies within
        the limits.
    """
    if period <= 0:
        raise ValueError(f"period must be positive; got {period!r}")
    k = round((previous - target) / period)
    best: float | None = None
    for kk in (k - 1, k, k + 1):
        cand = target + kk * period
        if lo - 1e-9 <= cand <= hi + 1e-9 and (
            best is None or abs(cand - previous) < abs(best - previous) - 1e-12
        ):
            best = cand
    if best is None and math.isfinite(lo) and math.isfinite(hi):
        # Far from the previous value: scan the representatives inside the limits.
        k0 = math.ceil((lo - target) / period - 1e-12)
        cands = [target + k * period for k in range(k0, k0 + int((hi - lo) / period) + 2)]
        cands = [c for c in cands if lo - 1e-9 <= c <= hi + 1e-9]
        if cands:
            best = min(cands, key=lambda c: abs(c - previous))
    return best


def unwrap_sequence(
    angles: np.ndarray, *, start: float = 0.0, period: float = 360.0
) -> np.ndarray:
    """Unwrap a sequence of orientations so each step is the shortest one.

    Parameters
    ----------
    angles
        Orientations, degrees (any representatives).
    start
        Axis coordinate before the first one, degrees.
    period
        Symmetry period, degrees.

    Returns
    -------
    ndarray
        Coordinates with ``|a[i] − a[i−1]| ≤ period/2``.
    """
    a = np.asarray(angles, dtype=float)
    d = np.diff(np.concatenate([[start], a]))
    d = (d + period / 2) % period - period / 2
    return start + np.cumsum(d)


def arc_points(
    start: tuple[float, float],
    end: tuple[float, float],
    center: tuple[float, float],
    *,
    clockwise: bool,
    chord_tolerance: float = 0.002,
) -> np.ndarray:
    """Points along a G2/G3 arc, the last one exactly ``end``.

    Parameters
    ----------
    start, end, center
        XY positions, mm (``center`` = start + (I, J)).
    clockwise
        True for G2.
    chord_tolerance
        Largest distance between the arc and its chords, mm.

    Returns
    -------
    ndarray (k, 2)
        The points after ``start``, ending with ``end``. A start equal to
        the end is a full circle, as in Marlin.
    """
    sx, sy = start
    ex, ey = end
    cx, cy = center
    r0 = math.hypot(sx - cx, sy - cy)
    r1 = math.hypot(ex - cx, ey - cy)
    a0 = math.atan2(sy - cy, sx - cx)
    a1 = math.atan2(ey - cy, ex - cx)
    sweep = a1 - a0
    if clockwise:
        if sweep >= -1e-12:
            sweep -= 2 * math.pi
    elif sweep <= 1e-12:
        sweep += 2 * math.pi
    r = max(r0, r1, 1e-12)
    tol = max(chord_tolerance, 1e-9)
    step = 2 * math.acos(max(-1.0, 1 - tol / r)) if tol < r else math.pi / 2
    n = max(1, math.ceil(abs(sweep) / max(step, 1e-6)))
    t = np.arange(1, n + 1) / n
    ang = a0 + sweep * t
    rad = r0 + (r1 - r0) * t  # Marlin blends the radius linearly too
    pts = np.column_stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)])
    pts[-1] = (ex, ey)
    return pts


def bead_area(width: float | np.ndarray, height: float, *, model: str = "rounded"):
    """Cross-section of a bead, mm².

    Parameters
    ----------
    width, height
        Bead width and layer height, mm.
    model
        ``"rounded"``: rectangle with semicircular ends (the Slic3r /
        PrusaSlicer model, valid for ``width ≥ height``); ``"rectangle"``:
        ``w·h``.
    """
    if model == "rounded":
        # a number without numpy's scalar cost (the writer asks once per move); same value
        w = max(width, height) if isinstance(width, float) else np.maximum(width, height)
        return w * height - height * height * (1.0 - math.pi / 4.0)
    if model == "rectangle":
        return width * height
    raise ValueError(f"unknown bead model {model!r}; expected one of: {', '.join(BEAD_MODELS)}")


def e_per_mm(width, height: float, filament_diameter: float, *, model: str = "rounded"):
    """Filament length per mm of bead: bead area / filament cross-section."""
    return bead_area(width, height, model=model) / (math.pi * filament_diameter**2 / 4.0)


def width_from_e(e_per_length, height: float, filament_diameter: float, *,
                 model: str = "rounded"):
    """Invert :func:`e_per_mm`: the bead width a slicer planned for this E per mm."""
    area = np.asarray(e_per_length, dtype=float) * (math.pi * filament_diameter**2 / 4.0)
    if model == "rounded":
        return area / height + height * (1.0 - math.pi / 4.0)
    if model == "rectangle":
        return area / height
    raise ValueError(f"unknown bead model {model!r}; expected one of: {', '.join(BEAD_MODELS)}")


def feed_for_move(
    feed_xy: float,
    xy_length: float,
    rotation: float,
    *,
    policy: str,
    rotary_feed: float,
) -> float:
    """The F word for one move, given the wanted XY speed.

    Parameters
    ----------
    feed_xy
        Wanted tool-tip XY speed, mm/min.
    xy_length
        XY length of the move, mm.
    rotation
        Rotary step of the move, degrees (signed or not).
    policy
        ``"xy"`` (Marlin ≥ 2.1, Klipper, RepRapFirmware with rotational axes:
        F is the XY speed, or °/min for a rotation-only move), ``"euclidean"``
        (the firmware treats degrees as mm and moves at F along the
        Euclidean length √(L² + Δφ²): F is scaled by that length over L so the
        XY speed is kept) or ``"inverse-time"`` (G93: F is 1 / duration in
        minutes).
    rotary_feed
        Top speed of the rotary axis, °/min: the speed of a rotation-only move,
        and the limit of a move's turn (``euclidean`` and ``inverse-time`` then
        lengthen the move; under ``xy`` the firmware does it).
    """
    dphi = abs(rotation)
    if xy_length <= 1e-12:
        if policy == "inverse-time":
            return rotary_feed / max(dphi, 1e-9)
        return rotary_feed
    if policy == "xy":
        return feed_xy
    # a move lasts as long as its slower part: the XY motion at feed_xy or the turn at
    # rotary_feed (the axis cannot turn faster; F2018025 for a 90° turn over 0.05 mm
    # would ask it to)
    slow_turn = dphi * feed_xy > rotary_feed * xy_length
    if policy == "euclidean":
        if slow_turn:
            return rotary_feed * math.hypot(xy_length, dphi) / dphi
        return feed_xy * math.hypot(xy_length, dphi) / xy_length
    if policy == "inverse-time":
        return rotary_feed / dphi if slow_turn else feed_xy / xy_length
    raise ValueError(f"unknown feed policy {policy!r}")
