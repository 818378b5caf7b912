"""T-T-R kinematics of the virtual printer: positions, modes, limits, arcs, move times.

Axes are kept in *native* machine coordinates ``(x, y, z, c)`` (mm, mm, mm,
degrees) plus the extruder position ``e`` (mm of filament). G92 shifts the
logical frame like Marlin's workspace offset: logical = native + offset, and
soft endstops apply to native coordinates. E is relative under M83 *or* G91
(Marlin's rule: G90 does not undo M83).

Feed semantics (:data:`printability.options.FEED_POLICIES`):

``xy``
    F (mm/min) is the speed of the linear axes; the rotary axis follows in the
    same time. A rotary-only move reads F as degrees/min (Marlin ≥ 2.1).
``euclidean``
    Degrees count as millimetres in the move length (older firmwares).
``inverse-time``
    Under G93, F is 1/minutes: each move lasts 60/F seconds.

Move time: a trapezoid per block (constant acceleration up to the nominal
speed, cruise, deceleration), with junction speeds from Marlin's junction
deviation model looking one block ahead (a real planner looks 16 ahead, so
estimates are slightly pessimistic on dense curves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from printability.model.machine import Machine
from simulators.config import FirmwareProfile
from simulators.parsing import Command

__all__ = ["Block", "MotionError", "MotionState", "junction_speed", "trapezoid_time"]


class MotionError(Exception):
    """A move the firmware refuses (Klipper's 'Move out of range'); the text is the reply."""


@dataclass
class Block:
    """One planner block (a straight segment), native coordinates.

    Attributes
    ----------
    start, end
        (x, y, z, c) at the ends, mm and degrees.
    e0, e1
        Extruder position at the ends, mm.
    length
        Length the speed applies to, mm (or degrees for a rotary-only move).
    speed
        Nominal speed, units of ``length`` per second.
    accel
        Acceleration, units of ``length`` per s².
    fixed_time
        Duration imposed by G93 inverse-time feed, s, or None.
    direction
        Unit vector of the XY(Z) motion, or None.
    duration
        Filled in when the planner starts the block, s.
    index
        Index of the command that made the block in the executed log.
    """

    start: np.ndarray
    end: np.ndarray
    e0: float
    e1: float
    length: float
    speed: float
    accel: float
    fixed_time: float | None = None
    direction: np.ndarray | None = None
    duration: float = 0.0
    exit_speed: float = 0.0
    index: int = -1  # the command's place in the executed log


def trapezoid_time(length: float, v_entry: float, v_exit: float, v_max: float,
                   accel: float) -> float:
    """Time to travel ``length`` from ``v_entry`` to ``v_exit`` with cruise ``v_max``, s."""
    if length <= 0:
        return 0.0
    v = max(v_max, 1e-9)
    ve, vx = min(v_entry, v), min(v_exit, v)
    da = (v * v - ve * ve) / (2 * accel)
    dd = (v * v - vx * vx) / (2 * accel)
    if da + dd <= length:
        return (v - ve) / accel + (v - vx) / accel + (length - da - dd) / v
    vp = math.sqrt(max((2 * accel * length + ve * ve + vx * vx) / 2, 0.0))
    if vp < max(ve, vx):  # the one-block look-ahead cannot always brake in time
        return 2 * length / max(ve + vx, 1e-9)
    return (vp - ve) / accel + (vp - vx) / accel


def junction_speed(a: Block, b: Block, jd: float) -> float:
    """Marlin's junction-deviation cornering speed between two blocks, units/s."""
    if a.direction is None or b.direction is None or a.fixed_time or b.fixed_time:
        return 0.0
    cos_theta = -float(np.dot(a.direction, b.direction))
    vmax = min(a.speed, b.speed)
    if cos_theta < -0.999999:  # straight on
        return vmax
    if cos_theta > 0.999999:  # reversal
        return 0.0
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    acc = min(a.accel, b.accel)
    v = math.sqrt(acc * jd * sin_half / max(1.0 - sin_half, 1e-9))
    # b must still be able to stop from its entry speed within its own length.
    return min(v, vmax, math.sqrt(2 * b.accel * b.length))


class MotionState:
    """Positions and modes of the printer, and the blocks a motion command makes."""

    def __init__(self, machine: Machine, fw: FirmwareProfile) -> None:
        self.machine = machine
        # what F means on a move that turns: the machine's policy, else its flavor's
        self.feed_policy = machine.feed_policy_for(machine.firmware())
        self.fw = fw
        self.letter = machine.rotary_letter if machine.has_rotary else None
        bed = machine.bed or (-math.inf, math.inf, -math.inf, math.inf)
        lo_c, hi_c = (-math.inf, math.inf)
        if machine.has_rotary and not machine.full_turn:
            lo_c, hi_c = machine.angle_min, machine.angle_max
        self.lo = np.array([bed[0], bed[2], 0.0, lo_c])
        self.hi = np.array([bed[1], bed[3], fw.z_max, hi_c])
        self.reset()

    def reset(self) -> None:
        # A board reset loses the firmware's idea of where the nozzle is, not the nozzle's
        # physical place: keep the native position (what the deposition record is drawn in)
        # and restart the logical frame at 0 there, as real firmware reports after a reset.
        pos = getattr(self, "pos", None)
        self.pos = np.zeros(4) if pos is None else pos  # native x, y, z, c
        self.offset = -self.pos.copy()
        self.e = 0.0
        self.relative = False
        self.e_relative = False
        self.feed = 50.0  # mm/s, Marlin's power-on feed rate
        self.inverse_time = False
        self.homed = False
        self.feed_percent = 100.0
        # M204 / M203 change these at run time.
        self.acceleration = self.fw.acceleration
        self.max_feed_xy = self.fw.max_feed_xy

    # -------------------------------------------------------------- helpers
    def logical(self) -> np.ndarray:
        return self.pos + self.offset

    def _letters(self) -> tuple[str, ...]:
        return ("X", "Y", "Z", self.letter or "")

    def target(self, cmd: Command) -> tuple[np.ndarray, float]:
        """Native target and new E of a G0/G1/G2/G3 (unclamped)."""
        tgt = self.pos.copy()
        for i, L in enumerate(self._letters()):
            if not L:
                continue
            v = cmd.words.get(L)
            if v is None:
                continue
            tgt[i] = self.pos[i] + v if self.relative else v - self.offset[i]
        e = self.e
        ev = cmd.words.get("E")
        if ev is not None:
            e = self.e + ev if (self.relative or self.e_relative) else ev
        return tgt, e

    def limit(self, tgt: np.ndarray, text: str) -> np.ndarray:
        """Apply the soft endstops: clamp (Marlin) or refuse (Klipper)."""
        if self.fw.endstops == "clamp":
            return np.clip(tgt, self.lo, self.hi)
        if np.any(tgt < self.lo - 1e-9) or np.any(tgt > self.hi + 1e-9):
            log = tgt + self.offset
            raise MotionError(f"!! Move out of range: {log[0]:.3f} {log[1]:.3f} {log[2]:.3f} "
                              f"[{self.e:.3f}]")
        return tgt

    def set_feed(self, cmd: Command) -> None:
        f = cmd.words.get("F")
        if f is not None and f > 0:
            self.feed = f if self.inverse_time else f / 60.0

    # -------------------------------------------------------------- blocks
    def _block(self, a: np.ndarray, b: np.ndarray, e0: float, e1: float,
               fixed: float | None) -> Block:
        fw = self.fw
        d = b - a
        lin = float(math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2))
        dc, de = abs(float(d[3])), abs(e1 - e0)
        direction = None
        feed = self.feed * self.feed_percent / 100.0
        if self.feed_policy == "euclidean":
            length = math.sqrt(lin * lin + dc * dc)
            speed, accel = min(feed, self.max_feed_xy), self.acceleration
            if lin > 0:
                direction = d[:3] / lin
        elif lin > 0:
            length, accel = lin, self.acceleration
            cap = fw.max_feed_z if lin == abs(d[2]) else self.max_feed_xy
            speed = min(feed, cap)
            if dc > 0:  # the rotary axis must keep up in the same time
                speed = min(speed, lin * fw.max_feed_rotary / dc)
            if de > 0:
                speed = min(speed, lin * fw.max_feed_e / de)
            direction = d[:3] / lin
        elif dc > 0:
            length, accel = dc, fw.rotary_acceleration
            speed = min(feed, fw.max_feed_rotary)
        else:
            length, accel = de, self.acceleration
            speed = min(feed, fw.max_feed_e)
        return Block(a.copy(), b.copy(), e0, e1, length, max(speed, 1e-6), accel, fixed,
                     direction)

    def linear(self, cmd: Command) -> list[Block]:
        """Blocks of a G0/G1 (updates the position)."""
        self.set_feed(cmd)
        tgt, e = self.target(cmd)
        tgt = self.limit(tgt, cmd.text)
        fixed = None
        if self.inverse_time:
            fixed = 60.0 / max(self.feed, 1e-9)
        out = []
        if np.any(tgt != self.pos) or e != self.e:
            out.append(self._block(self.pos, tgt, self.e, e, fixed))
        self.pos, self.e = tgt, e
        return out

    def arc(self, cmd: Command, clockwise: bool) -> list[Block]:
        """Blocks of a G2/G3 in the XY plane, linearised like Marlin's plan_arc."""
        self.set_feed(cmd)
        tgt, e = self.target(cmd)
        p0 = self.pos.copy()
        i, j, r = cmd.words.get("I"), cmd.words.get("J"), cmd.words.get("R")
        dx, dy = tgt[0] - p0[0], tgt[1] - p0[1]
        if r is not None and i is None and j is None:
            # Center from the radius (Marlin: negative R picks the long way round).
            d2 = dx * dx + dy * dy
            h2 = r * r - d2 / 4
            if d2 == 0 or h2 < -1e-9:
                raise MotionError("echo:Arc radius too small for the endpoints; move skipped")
            h = math.sqrt(max(h2, 0.0)) / math.sqrt(d2)
            sgn = -1.0 if (clockwise ^ (r < 0)) else 1.0
            ci, cj = dx / 2 - sgn * dy * h, dy / 2 + sgn * dx * h
        else:
            ci, cj = i or 0.0, j or 0.0
        cx, cy = p0[0] + ci, p0[1] + cj
        radius = math.hypot(ci, cj)
        if radius == 0:
            return self.linear(cmd)
        a0 = math.atan2(p0[1] - cy, p0[0] - cx)
        a1 = math.atan2(tgt[1] - cy, tgt[0] - cx)
        travel = a1 - a0
        if clockwise:
            if travel >= -1e-12:
                travel -= 2 * math.pi
        elif travel <= 1e-12:
            travel += 2 * math.pi
        if math.hypot(dx, dy) < 1e-9:  # same start and end: a full circle
            travel = -2 * math.pi if clockwise else 2 * math.pi
        flat = abs(travel) * radius
        n = max(1, math.ceil(flat / self.fw.arc_segment),
                math.ceil(self.fw.arc_min_segments * abs(travel) / (2 * math.pi)))
        ts = np.arange(1, n + 1) / n
        pts = np.empty((n, 4))
        pts[:, 0] = cx + radius * np.cos(a0 + travel * ts)
        pts[:, 1] = cy + radius * np.sin(a0 + travel * ts)
        pts[:, 2] = p0[2] + (tgt[2] - p0[2]) * ts
        pts[:, 3] = p0[3] + (tgt[3] - p0[3]) * ts
        pts[-1, :2] = tgt[:2]  # land exactly on the programmed end point
        es = self.e + (e - self.e) * ts
        fixed = None
        if self.inverse_time:
            fixed = 60.0 / max(self.feed, 1e-9) / n
        out = []
        prev, pe = p0, self.e
        for k in range(n):
            q = self.limit(pts[k], cmd.text)
            out.append(self._block(prev, q, pe, float(es[k]), fixed))
            prev, pe = q, float(es[k])
        self.pos, self.e = prev, e
        return out

    def set_position(self, cmd: Command) -> None:
        """G92: the current position now reads as the given values."""
        any_axis = False
        for i, L in enumerate(self._letters()):
            if L and L in cmd.words:
                any_axis = True
                v = cmd.words[L]
                if v is not None:
                    self.offset[i] = v - self.pos[i]
        if "E" in cmd.words:
            any_axis = True
            if cmd.words["E"] is not None:
                self.e = cmd.words["E"]
        if not any_axis:  # bare G92 zeroes every axis (Marlin)
            self.offset = -self.pos.copy()
            self.e = 0.0

    def home(self, cmd: Command) -> None:
        """G28: move the named axes (all when none is named) to their home (min, rotary 0)."""
        letters = self._letters()
        named = [i for i, L in enumerate(letters) if L and L in cmd.words]
        axes = named or [i for i, L in enumerate(letters) if L]
        for i in axes:
            home = self.lo[i] if i < 3 and math.isfinite(self.lo[i]) else 0.0
            self.pos[i] = min(max(home, self.lo[i]), self.hi[i])
            self.offset[i] = 0.0
        self.homed = True
