"""How long a G-code file takes to print: Klipper's motion planner, replayed.

A user's speed includes print time, and the seed ranks nozzles by accuracy *and then build
time*; a rewritten file that turns the nozzle can print much slower than the slicer's (a
rotation-only move is a full stop on Klipper). This module replays the look-ahead planner of
Klipper's host (``klippy/toolhead.py`` v0.13: ``Move``, ``calc_junction``, ``LookAheadQueue.
flush``; ``extras/gcode_arcs.py``; ``kinematics/extruder.py`` and
``extras/manual_stepper.py``'s limits) over a parsed file, vectorised in one compiled pass:

* each move's length is its XYZ length, or for a move with no XYZ motion (E only, C only) the
  largest extra-axis delta, and F is read accordingly (mm/min, or degrees per minute on a
  rotation-only move);
* limits: ``max_velocity`` (not on moves without XYZ motion), ``max_accel`` (M204 S or
  min(P, T), ``SET_VELOCITY_LIMIT``), Z's velocity and acceleration scaled by the Z share,
  extrude-only and retraction moves by the extruder's limits, moves that turn by the rotary
  axis's ``LIMIT_VELOCITY`` / ``LIMIT_ACCEL`` scaled by the turn's share;
* junctions: zero to or from a move with no XYZ motion; otherwise the smallest of the cruise
  speeds, the extruder's and the rotary axis's ``instantaneous_corner_velocity / |Δratio|``
  and the junction-deviation circle from ``square_corner_velocity``;
* the trapezoids of the look-ahead with ``minimum_cruise_ratio``; a full stop at every
  ``M400``, ``G4`` (its dwell added), ``G28`` and ``MANUAL_STEPPER`` command;
* arcs linearised as ``gcode_arcs`` does (``floor(length / resolution)`` segments).

Homing moves, heating waits and the time before the first move are not counted. Checked
against klippy in batch mode on the shared slicer samples (``tests/gcode/test_printtime.py``).

Complexity: linear in the moves (and arc segments).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from gcode.flavors import PlannerLimits, RotaryAxis
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["PlannerLimits", "PrintTime", "estimate_print_time", "format_duration"]


@dataclass(frozen=True)
class PrintTime:
    """The planned print time of a file (seconds).

    Attributes
    ----------
    total
        Motion plus dwells.
    motion
        Sum of the planned moves' durations.
    dwell
        G4 dwells.
    moves
        Planned moves (arcs counted by segment).
    stops
        Moves with XYZ motion that start from rest.
    rotation_only, rotation_only_time
        Moves that only turn the rotary axis, and the time they take.
    """

    total: float
    motion: float
    dwell: float
    moves: int
    stops: int
    rotation_only: int
    rotation_only_time: float


def format_duration(seconds: float) -> str:
    """``1h 02m 03s`` / ``2m 05s`` / ``41s``."""
    s = round(seconds)
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    if h:
        return f"{h}h {m:02d}m {s:02d}s"
    return f"{m}m {s:02d}s" if m else f"{s}s"


# one command of the stream: what changes the planner between moves
_SET_ACCEL, _SET_VELOCITY, _SET_SCV, _SET_MCR, _DWELL, _STOP = 1, 2, 3, 4, 5, 6
_EXTENDED = re.compile(rb"(?i)^\s*(SET_VELOCITY_LIMIT|MANUAL_STEPPER)\b([^;\r\n]*)")
_PARAM = re.compile(rb"(?i)\b([A-Z_]+)=([-+]?[0-9.]+(?:e[-+]?\d+)?)")


def _events(g, letter: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(line, code, value) of the commands that change the planner, in line order."""
    lines = g.lines
    words = g.words
    out: list[tuple[int, int, float]] = []
    cmd = (lines["kind"] == 2)
    letters = lines["letter"]
    major = lines["major"]

    def word(li: int, ch: str) -> float | None:
        a = int(lines["word_first"][li])
        b = a + int(lines["word_count"][li])
        sel = words[a:b]
        hit = sel["value"][sel["letter"] == ord(ch)]
        return float(hit[0]) if hit.size and math.isfinite(hit[0]) else None

    for li in np.flatnonzero(cmd & (letters == ord("M")) & np.isin(major, (204, 400))).tolist():
        if major[li] == 400:
            out.append((li, _STOP, 0.0))
            continue
        s = word(li, "S")
        if s is None:
            p, t = word(li, "P"), word(li, "T")
            s = min(p, t) if p is not None and t is not None else None
        if s is not None and s > 0:
            out.append((li, _SET_ACCEL, s))
    for li in np.flatnonzero(cmd & (letters == ord("G")) & np.isin(major, (4, 28))).tolist():
        if major[li] == 28:
            out.append((li, _STOP, 0.0))
            continue
        p = word(li, "P")  # Klipper reads only P (milliseconds)
        out.append((li, _DWELL, max(p or 0.0, 0.0) / 1000.0))
    data = g.data
    starts = lines["start"]
    ends = np.r_[starts[1:], len(data)]
    # extended commands are rare: find them by their first letters, then read them
    cand = np.flatnonzero(~cmd & ((letters == ord("S")) | (letters == ord("M"))
                                  | (letters == ord("s")) | (letters == ord("m"))))
    for li in cand.tolist():
        m = _EXTENDED.match(data[starts[li]:ends[li]])
        if m is None:
            continue
        if m.group(1).upper() == b"MANUAL_STEPPER":
            out.append((li, _STOP, 0.0))
            continue
        for key, value in _PARAM.findall(m.group(2)):
            code = {b"ACCEL": _SET_ACCEL, b"VELOCITY": _SET_VELOCITY,
                    b"SQUARE_CORNER_VELOCITY": _SET_SCV,
                    b"MINIMUM_CRUISE_RATIO": _SET_MCR}.get(key.upper())
            if code is not None:
                out.append((li, code, float(value)))
    out.sort()
    arr = np.array(out, dtype=float).reshape(-1, 3)
    return arr[:, 0].astype(np.int64), arr[:, 1].astype(np.int64), arr[:, 2]


def _rotary_track(g, moves: np.ndarray, letter: str) -> np.ndarray:
    """The rotary coordinate after each move (degrees; 0 before the first word)."""
    w = g.words
    sel = (w["letter"] == ord(letter.upper())) & np.isfinite(w["value"])
    if not sel.any():
        return np.zeros(len(moves))
    by_line = np.full(len(g.lines), np.nan)
    by_line[w["line"][sel]] = w["value"][sel]
    val = by_line[moves["line"]]
    have = np.isfinite(val)
    rel = have & ((moves["flags"] & 2) != 0)
    if rel.any():  # G91 with rotary words (rare): sums, in order
        c = np.where(have, val, 0.0)
        out = np.empty(len(moves))
        acc = 0.0
        for i, (v, h, r) in enumerate(zip(c.tolist(), have.tolist(), rel.tolist(),
                                          strict=True)):
            if h:
                acc = acc + v if r else v
            out[i] = acc
        return out
    # absolute words: each move's coordinate is the last word's, forward-filled
    last = np.maximum.accumulate(np.where(have, np.arange(len(moves)), -1))
    return np.where(last >= 0, val[np.maximum(last, 0)], 0.0)


def estimate_print_time(g, *, limits: PlannerLimits | None = None,
                        rotary: RotaryAxis | None = None) -> PrintTime:
    """The print time Klipper's planner gives a parsed file (:func:`gcode.parse_gcode`).

    Parameters
    ----------
    g
        The parsed file.
    limits
        The printer's limits (None: Klipper's defaults, :class:`PlannerLimits`).
    rotary
        The rotary nozzle axis (its letter, ``max_speed`` as ``LIMIT_VELOCITY``,
        ``acceleration`` as ``LIMIT_ACCEL``, ``corner_velocity`` as
        ``INSTANTANEOUS_CORNER_VELOCITY``); None: rotary words are not moves.

    Returns
    -------
    PrintTime
    """
    limits = PlannerLimits() if limits is None else limits
    m = g.moves
    n = len(m)
    if n == 0:
        return PrintTime(0.0, 0.0, 0.0, 0, 0, 0, 0.0)
    c1 = _rotary_track(g, m, rotary.letter) if rotary is not None else np.zeros(n)
    ev_line, ev_code, ev_val = _events(g, rotary.letter if rotary else "C")
    ev_at = np.searchsorted(m["line"], ev_line, side="left").astype(np.int64)
    e_v, e_a = limits.extruder_limits()
    rot = np.array([rotary.max_speed, rotary.acceleration, rotary.corner_velocity]
                   if rotary is not None else [1e9, 1e9, 1e9])
    lim = np.array([limits.max_velocity, limits.max_accel, limits.square_corner_velocity,
                    limits.minimum_cruise_ratio, limits.max_z_velocity, limits.max_z_accel,
                    e_v, e_a, limits.extruder_corner_velocity, limits.arc_resolution])
    cols = np.column_stack([m["x0"], m["y0"], m["z0"], m["x1"], m["y1"], m["z1"], m["e"],
                            m["feed"], m["cx"], m["cy"], m["sweep"], m["r0"], c1]).astype(float)
    kinds = m["kind"].astype(np.int64)
    out = _plan(cols, kinds, (ev_at, ev_code, ev_val), lim, rot)
    return PrintTime(total=float(out[0] + out[1]), motion=float(out[0]), dwell=float(out[1]),
                     moves=int(out[2]), stops=int(out[3]), rotation_only=int(out[4]),
                     rotation_only_time=float(out[5]))


@numba.njit(cache=True, nogil=True)
def _segments(cols, kinds, res):  # pragma: no cover
    """The moves as planner segments: (dx, dy, dz, de, dc, speed mm/s, move index) rows,
    arcs linearised as gcode_arcs does; moves from an unknown position are skipped."""
    n = cols.shape[0]
    count = 0
    for i in range(n):
        if kinds[i] >= 2 and math.isfinite(cols[i, 10]):
            length = abs(cols[i, 11] * cols[i, 10])
            count += max(1, math.floor(length / res))
        else:
            count += 1
    seg = np.empty((count, 7))
    k = 0
    c_prev = 0.0
    for i in range(n):
        x0, y0, z0 = cols[i, 0], cols[i, 1], cols[i, 2]
        x1, y1, z1 = cols[i, 3], cols[i, 4], cols[i, 5]
        de = cols[i, 6]
        f = cols[i, 7] / 60.0
        c = cols[i, 12]
        dc = c - c_prev
        c_prev = c
        if not math.isfinite(f) or f <= 0:
            f = 25.0  # Klipper's speed before any F
        # a coordinate not known yet is where homing leaves it, 0 (as Klipper's batch mode
        # and most printers): the first move of a file starts there
        if not math.isfinite(x0):
            x0 = x1 if not math.isfinite(x1) else 0.0
        if not math.isfinite(y0):
            y0 = y1 if not math.isfinite(y1) else 0.0
        if not math.isfinite(z0):
            z0 = z1 if not math.isfinite(z1) else 0.0
        if not math.isfinite(x1):
            x0 = x1 = 0.0
        if not math.isfinite(y1):
            y0 = y1 = 0.0
        if not math.isfinite(z1):
            z0 = z1 = 0.0
        known = True
        if kinds[i] >= 2 and math.isfinite(cols[i, 10]) and known:
            cx, cy, sweep, r = cols[i, 8], cols[i, 9], cols[i, 10], cols[i, 11]
            nseg = max(1, math.floor(abs(r * sweep) / res))
            a0 = math.atan2(y0 - cy, x0 - cx)
            px, py, pz = x0, y0, z0
            for j in range(1, nseg + 1):
                if j == nseg:
                    qx, qy = x1, y1
                else:
                    a = a0 + sweep * j / nseg
                    qx = cx + r * math.cos(a)
                    qy = cy + r * math.sin(a)
                qz = z0 + (z1 - z0) * j / nseg
                seg[k, 0] = qx - px
                seg[k, 1] = qy - py
                seg[k, 2] = qz - pz
                seg[k, 3] = de / nseg
                seg[k, 4] = dc if j == 1 else 0.0
                seg[k, 5] = f
                seg[k, 6] = i
                px, py, pz = qx, qy, qz
                k += 1
        else:
            seg[k, 0] = x1 - x0
            seg[k, 1] = y1 - y0
            seg[k, 2] = z1 - z0
            seg[k, 3] = de if math.isfinite(de) else 0.0
            seg[k, 4] = dc
            seg[k, 5] = f
            seg[k, 6] = i
            k += 1
    return seg[:k]


# The helpers called per planned move allocate nothing, so they skip reference counting: a
# count on each of the queue's arrays at every call would cost more than their work and keep
# LLVM from inlining them.
_helper = numba.njit(cache=True, nogil=True, _nrt=False)


class _Queue(NamedTuple):
    """The look-ahead queue: one row per planned move (Klipper's ``Move`` fields)."""

    move_d: np.ndarray  # length, mm (or the largest extra-axis delta)
    accel: np.ndarray
    max_cruise_v2: np.ndarray
    delta_v2: np.ndarray
    mcr_delta_v2: np.ndarray  # delta_v2 under minimum_cruise_ratio
    max_start_v2: np.ndarray
    max_mcr_start_v2: np.ndarray
    jd: np.ndarray  # junction deviation (from square_corner_velocity), mm
    rx: np.ndarray  # axis ratios (delta / length)
    ry: np.ndarray
    rz: np.ndarray
    re: np.ndarray
    rc: np.ndarray
    kin: np.ndarray  # has XYZ motion
    stop_after: np.ndarray  # the queue is flushed (a full stop) after it


# The planner's current limits and running totals (a float64 array the helpers update).
_CUR_V, _CUR_A, _CUR_SCV, _CUR_MCR, _CUR_DWELL, _CUR_ROT_ONLY, _CUR_ROT_TIME = range(7)


@numba.njit(cache=True, nogil=True)
def _new_queue(n):  # pragma: no cover
    return _Queue(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n),
                  np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n),
                  np.zeros(n), np.zeros(n, np.bool_), np.zeros(n, np.bool_))


@numba.njit(cache=True, nogil=True)
def _flush(q, q0, q1):  # pragma: no cover
    """LookAheadQueue.flush(lazy=False) over moves q0..q1-1: their total duration."""
    m = q1 - q0
    start_v2 = np.empty(m)
    cruise_v2 = np.full(m, -1.0)
    next_v2 = np.empty(m)
    next_start_v2 = 0.0
    next_mcr_start_v2 = 0.0
    peak_cruise_v2 = 0.0
    pending = 0
    for j in range(m - 1, -1, -1):
        i = q0 + j
        reachable = next_start_v2 + q.delta_v2[i]
        sv2 = min(q.max_start_v2[i], reachable)
        pending += 1
        reach_mcr = next_mcr_start_v2 + q.mcr_delta_v2[i]
        mcr_sv2 = min(q.max_mcr_start_v2[i], reach_mcr)
        if mcr_sv2 < reach_mcr:
            if mcr_sv2 + q.mcr_delta_v2[i] > next_mcr_start_v2 or pending > 1:
                peak_cruise_v2 = (mcr_sv2 + reach_mcr) * 0.5
            cruise_v2[j] = min((sv2 + reachable) * 0.5, q.max_cruise_v2[i], peak_cruise_v2)
            pending = 0
        start_v2[j] = sv2
        next_v2[j] = next_start_v2
        next_start_v2 = sv2
        next_mcr_start_v2 = mcr_sv2
    total = 0.0
    prev_cruise = 0.0
    for j in range(m):
        i = q0 + j
        cv2 = cruise_v2[j]
        if cv2 < 0:
            cv2 = min(prev_cruise, start_v2[j])
        s2 = min(start_v2[j], cv2)
        e2 = min(next_v2[j], cv2)
        half_inv = 0.5 / q.accel[i]
        accel_d = (cv2 - s2) * half_inv
        decel_d = (cv2 - e2) * half_inv
        cruise_d = q.move_d[i] - accel_d - decel_d
        sv = math.sqrt(s2)
        cv = math.sqrt(cv2)
        ev = math.sqrt(e2)
        t = 0.0
        if cv > 0:
            t = accel_d / ((sv + cv) * 0.5) + cruise_d / cv + decel_d / ((ev + cv) * 0.5)
        total += t
        prev_cruise = cv2
    return total


@_helper
def _apply_events(events, e, mi, cur, q, prev):  # pragma: no cover
    """Apply the commands before move ``mi`` from event ``e`` on (limits, stops, dwells);
    the next event."""
    ev_at, ev_code, ev_val = events
    while e < len(ev_at) and ev_at[e] <= mi:
        code = ev_code[e]
        v = ev_val[e]
        if code == _SET_ACCEL:
            cur[_CUR_A] = v
        elif code == _SET_VELOCITY:
            cur[_CUR_V] = v
        elif code == _SET_SCV:
            cur[_CUR_SCV] = v
        elif code == _SET_MCR:
            cur[_CUR_MCR] = v
        elif code == _DWELL or code == _STOP:
            if prev >= 0:
                q.stop_after[prev] = True
            if code == _DWELL:
                cur[_CUR_DWELL] += v
        e += 1
    return e


@_helper
def _add_move(q, p, seg, k, cur, lim, rot):  # pragma: no cover
    """Put segment ``k`` in the queue as move ``p`` with its limits (Klipper's ``Move``);
    False for a segment that does not move (Klipper plans nothing)."""
    dx, dy, dz, de, dc, speed = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3], seg[k, 4], \
        seg[k, 5]
    max_a = cur[_CUR_A]
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    a = max_a
    if d < 1e-9:
        d = max(abs(de), abs(dc))
        if d == 0.0:
            return False
        is_kin = False
        a = 99999999.9
        v = speed
        dx = dy = dz = 0.0
    else:
        is_kin = True
        v = min(speed, cur[_CUR_V])
    inv = 1.0 / d
    cv2 = v * v
    # kinematics: Z
    if is_kin and dz != 0.0:
        zr = d / abs(dz)
        lv = lim[4] * zr
        if lv * lv < cv2:
            cv2 = lv * lv
        a = min(a, lim[5] * zr)
    # the extruder: E-only and retraction moves at its limits
    if de != 0.0 and ((dx == 0.0 and dy == 0.0) or de < 0.0):
        er = 1.0 / abs(de * inv)
        lv = lim[6] * er
        if lv * lv < cv2:
            cv2 = lv * lv
        a = min(a, lim[7] * er)
    # the rotary axis
    if dc != 0.0:
        cr = d / abs(dc)
        lv = rot[0] * cr
        if lv * lv < cv2:
            cv2 = lv * lv
        a = min(a, rot[1] * cr)
    q.move_d[p] = d
    q.accel[p] = a
    q.max_cruise_v2[p] = cv2
    q.delta_v2[p] = 2.0 * d * a
    q.mcr_delta_v2[p] = min(2.0 * d * max_a * (1.0 - cur[_CUR_MCR]), q.delta_v2[p])
    q.jd[p] = cur[_CUR_SCV] * cur[_CUR_SCV] * (math.sqrt(2.0) - 1.0) / max_a
    q.rx[p] = dx * inv
    q.ry[p] = dy * inv
    q.rz[p] = dz * inv
    q.re[p] = de * inv
    q.rc[p] = dc * inv
    q.kin[p] = is_kin
    if not is_kin and dc != 0.0 and de == 0.0:
        cur[_CUR_ROT_ONLY] += 1.0
        v = math.sqrt(cv2)
        cur[_CUR_ROT_TIME] += 2.0 * math.sqrt(d / a) if v * v / a >= d else d / v + v / a
    return True


@_helper
def _junction(q, p, prev, lim, rot):  # pragma: no cover
    """The junction of move ``p`` with the previous planned move (none across a stop):
    its largest start speeds, or a stop after ``prev``."""
    if prev >= 0 and not q.stop_after[prev] and q.kin[p] and q.kin[prev]:
        ms = min(q.max_cruise_v2[p], q.max_cruise_v2[prev],
                 q.max_start_v2[prev] + q.delta_v2[prev])
        dr = q.re[p] - q.re[prev]
        if dr != 0.0:
            ms = min(ms, (lim[8] / abs(dr)) ** 2)
        dr = q.rc[p] - q.rc[prev]
        if dr != 0.0:
            ms = min(ms, (rot[2] / abs(dr)) ** 2)
        cos_t = -(q.rx[p] * q.rx[prev] + q.ry[p] * q.ry[prev] + q.rz[p] * q.rz[prev])
        sin_d2 = math.sqrt(max(0.5 * (1.0 - cos_t), 0.0))
        cos_d2 = math.sqrt(max(0.5 * (1.0 + cos_t), 0.0))
        om = 1.0 - sin_d2
        if om > 0.0 and cos_d2 > 0.0:
            r_jd = sin_d2 / om
            qt = 0.25 * sin_d2 / cos_d2
            ms = min(ms, r_jd * q.jd[p] * q.accel[p], r_jd * q.jd[prev] * q.accel[prev],
                     q.delta_v2[p] * qt, q.delta_v2[prev] * qt)
        q.max_start_v2[p] = ms
        q.max_mcr_start_v2[p] = min(ms, q.max_mcr_start_v2[prev] + q.mcr_delta_v2[prev])
    elif prev >= 0:
        q.stop_after[prev] = True


@numba.njit(cache=True, nogil=True)
def _plan(cols, kinds, events, lim, rot):  # pragma: no cover
    """Totals: (motion s, dwell s, moves, stops, rotation-only moves, their time s)."""
    ev_at, ev_code, ev_val = events
    seg = _segments(cols, kinds, lim[9])
    n = seg.shape[0]
    q = _new_queue(n)
    cur = np.zeros(7)
    cur[_CUR_V] = lim[0]
    cur[_CUR_A] = lim[1]
    cur[_CUR_SCV] = lim[2]
    cur[_CUR_MCR] = lim[3]
    e = 0
    prev = -1  # the last planned move
    planned = 0
    for k in range(n):
        mi = int(seg[k, 6])
        # the commands before this move's line change the limits, stop, dwell
        if k == 0 or int(seg[k - 1, 6]) < mi:
            e = _apply_events(events, e, mi, cur, q, prev)
        if _add_move(q, planned, seg, k, cur, lim, rot):
            _junction(q, planned, prev, lim, rot)
            prev = planned
            planned += 1
    while e < len(ev_at):  # after the last move: only dwells count
        if ev_code[e] == _DWELL:
            cur[_CUR_DWELL] += ev_val[e]
        e += 1
    # flush the queue at every stop
    total = 0.0
    stops = 0
    q0 = 0
    for p in range(planned):
        if q.kin[p] and q.max_start_v2[p] == 0.0:
            stops += 1
        if q.stop_after[p] or p == planned - 1:
            total += _flush(q, q0, p + 1)
            q0 = p + 1
    return np.array([total, cur[_CUR_DWELL], float(planned), float(stops), cur[_CUR_ROT_ONLY],
                     cur[_CUR_ROT_TIME]])
