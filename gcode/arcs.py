"""Arc geometry: exact lengths and vectorised linearisation with a chord tolerance.

An arc move (G2/G3) is stored by :mod:`gcode._machine` as its centre, signed
sweep θ (radians, CCW positive) and start/end radii r₀, r₁ (equal up to the
slicer's rounding; when they differ the arc is taken as the spiral whose
radius varies linearly with the angle, so it ends exactly at the target,
which is what firmware does in effect). Z and E vary linearly with the
angle (helical moves).

A chord spanning the angle φ of a circle of radius r deviates from it by the
sagitta r·(1 − cos(φ/2)); choosing φ = 2·acos(1 − tol/r) bounds that by
``tol``. Each arc gets n = ⌈|θ|/φ⌉ chords of equal angle (at least one).
"""

from __future__ import annotations

import numpy as np

from printability.base.arrays import take_rows

__all__ = ["SEGMENT_DTYPE", "arc_chord_count", "arc_length", "linearise"]

SEGMENT_DTYPE = np.dtype(
    [("move", "i8"), ("x0", "f8"), ("y0", "f8"), ("z0", "f8"),
     ("x1", "f8"), ("y1", "f8"), ("z1", "f8"), ("e", "f8")]
)


def arc_chord_count(radius: np.ndarray, sweep: np.ndarray, tolerance: float) -> np.ndarray:
    """Chords needed so that no chord is farther than ``tolerance`` (mm) from the arc.

    Parameters
    ----------
    radius
        Largest radius of each arc, mm.
    sweep
        Signed sweep, radians.
    tolerance
        Maximum sagitta, mm (> 0).
    """
    r = np.asarray(radius, dtype=float)
    ratio = np.clip(1.0 - tolerance / np.maximum(r, 1e-300), -1.0, 1.0)
    phi = np.minimum(2.0 * np.arccos(ratio), np.pi / 2)
    phi = np.where(phi > 0, phi, np.pi / 2)
    return np.maximum(1, np.ceil(np.abs(sweep) / phi - 1e-12)).astype(np.int64)


def arc_length(r0: np.ndarray, r1: np.ndarray, sweep: np.ndarray) -> np.ndarray:
    """Exact XY length of a circular arc (r₀ = r₁) or, for r₀ ≠ r₁, of the
    Archimedean spiral between them, mm (numerical quadrature for spirals)."""
    r0 = np.asarray(r0, float)
    r1 = np.asarray(r1, float)
    s = np.abs(np.asarray(sweep, float))
    t = np.linspace(0.0, 1.0, 65)[:, None]
    # ds = sqrt(r(θ)^2 + (dr/dθ)^2) dθ ; Simpson's rule over 64 intervals
    dr = np.where(s > 0, (r1 - r0) / np.where(s > 0, s, 1.0), 0.0)
    f = np.sqrt((r0 + (r1 - r0) * t) ** 2 + dr**2)
    w = np.ones(65)
    w[1:-1:2] = 4
    w[2:-1:2] = 2
    return (w[:, None] * f).sum(axis=0) / (3 * 64) * s


def linearise(moves: np.ndarray, tolerance: float) -> np.ndarray:
    """Chord segments of every move: one per line move, n per arc.

    Parameters
    ----------
    moves
        A :data:`gcode.reader.MOVE_DTYPE` array.
    tolerance
        Chord tolerance, mm.

    Returns
    -------
    numpy structured array of :data:`SEGMENT_DTYPE`, in file order; ``move``
    is the row of ``moves`` each segment comes from. E (and Z) of an arc is
    shared evenly by its chords. Complexity O(total chords).
    """
    is_arc = moves["kind"] >= 2
    if not is_arc.any():
        # one chord per move: the general path's arithmetic at t0 = 0, t1 = 1 (to the bit,
        # signed zeros included), without gathering every move once per chord
        seg = np.empty(len(moves), SEGMENT_DTYPE)
        seg["move"] = np.arange(len(moves))
        for c in ("x", "y", "z"):
            a0, a1 = moves[c + "0"], moves[c + "1"]
            seg[c + "0"] = a0 + (a1 - a0) * 0.0
            seg[c + "1"] = a1
        seg["e"] = moves["e"] / 1.0
        return seg
    counts = np.ones(len(moves), np.int64)
    if is_arc.any():
        a = moves[is_arc]
        counts[is_arc] = arc_chord_count(np.fmax(a["r0"], a["r1"]), a["sweep"], tolerance)
    total = int(counts.sum())
    seg = np.empty(total, SEGMENT_DTYPE)
    idx = np.repeat(np.arange(len(moves)), counts)
    seg["move"] = idx
    first = np.cumsum(counts) - counts
    k = np.arange(total) - np.repeat(first, counts)  # chord number within its move
    n = counts[idx].astype(float)
    t0 = k / n
    t1 = (k + 1) / n
    m = take_rows(moves, idx)
    for c in ("x", "y", "z"):
        a0, a1 = m[c + "0"], m[c + "1"]
        seg[c + "0"] = a0 + (a1 - a0) * t0
        seg[c + "1"] = np.where(k + 1 == n, a1, a0 + (a1 - a0) * t1)
    seg["e"] = m["e"] / n
    arc = m["kind"] >= 2
    if arc.any():
        ma = m[arc]
        start_ang = np.arctan2(ma["y0"] - ma["cy"], ma["x0"] - ma["cx"])
        for t, cx_, cy_ in ((t0[arc], "x0", "y0"), (t1[arc], "x1", "y1")):
            ang = start_ang + ma["sweep"] * t
            r = ma["r0"] + (ma["r1"] - ma["r0"]) * t
            seg[cx_][arc] = ma["cx"] + r * np.cos(ang)
            seg[cy_][arc] = ma["cy"] + r * np.sin(ang)
        # chords meet exactly where the arc starts and ends
        ka = k[arc]
        na = n[arc]
        first_chord = ka == 0
        last_chord = ka + 1 == na
        for c in ("x", "y"):
            col0 = seg[c + "0"]
            col1 = seg[c + "1"]
            sub0 = col0[arc]
            sub1 = col1[arc]
            sub0[first_chord] = ma[c + "0"][first_chord]
            sub1[last_chord] = ma[c + "1"][last_chord]
            col0[arc] = sub0
            col1[arc] = sub1
            seg[c + "0"] = col0
            seg[c + "1"] = col1
    return seg
