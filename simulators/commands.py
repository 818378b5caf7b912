"""What each command does: moves, dwells, homing, heaters, modes, and the reports.

One generator per G/M-code (:meth:`CommandsMixin._run`, which looks the
code's handler up) yields what it waits for (see :mod:`simulators.planner`);
the M114 report is formatted here, the M105 and M115 ones by the firmware
profile (:mod:`simulators.profiles`), which also says which commands are
no-ops and what an unknown command gets. Also the first-order
:class:`Heater` the temperature commands drive. Mixed into :class:`simulators.firmware.Firmware`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterator
from typing import Any

from simulators.kinematics import MotionError
from simulators.line_protocol import Entry
from simulators.parsing import Command

__all__ = ["CommandsMixin", "Heater"]

COLD = "echo: cold extrusion prevented"

# Marlin's M113 (HOST_KEEPALIVE_FEATURE) caps the interval at 60 s (gcode/host/M113.cpp)
_M113_MAX = 60


class Heater:
    """First-order heater: T → setpoint (or ambient when off) with time constant ``tau``."""

    def __init__(self, ambient: float, tau: float) -> None:
        self.ambient, self.tau = ambient, tau
        self.t0, self.T0, self.target = 0.0, ambient, 0.0

    def _eq(self) -> float:
        return self.target if self.target > 0 else self.ambient

    def temp(self, t: float) -> float:
        eq = self._eq()
        return eq + (self.T0 - eq) * math.exp(-max(t - self.t0, 0.0) / self.tau)

    def set(self, target: float, t: float) -> None:
        self.T0, self.t0, self.target = self.temp(t), t, max(target, 0.0)

    def reach_time(self, t: float, window: float) -> float:
        """When the temperature comes within ``window`` °C of the setpoint, s."""
        eq, T = self._eq(), self.temp(t)
        gap = abs(T - eq)
        return t if gap <= window else t + self.tau * math.log(gap / window)

    def power(self, t: float) -> int:
        return 127 if self.target > 0 and self.temp(t) < self.target - 0.5 else 0


class CommandsMixin:
    """Command handlers and reports of :class:`simulators.firmware.Firmware`."""

    # ---------------------------------------------------------------- commands
    def _run(self, entry: Entry) -> Generator[Any, None, None]:
        """What command ``entry`` does, as a generator of what it waits for."""
        code = entry.cmd.code
        if code in self.fw.noop_codes:
            return
        handler = _HANDLERS.get(code)
        if handler is None and code.startswith("T"):
            handler = CommandsMixin._tool
        if handler is None:
            self._unknown(entry.cmd)
            return
        steps = handler(self, entry)
        if steps is not None:
            yield from steps

    def _move(self, entry: Entry) -> Generator[Any, None, None]:
        """G0-G3: plan the blocks, each waiting for a free planner slot; an extruding block
        below the minimum extrusion temperature moves without extruding."""
        cmd, m = entry.cmd, self.motion
        code = cmd.code
        try:
            if code in ("G0", "G1"):
                blocks = m.linear(cmd)
            else:
                blocks = m.arc(cmd, clockwise=code == "G2")
        except MotionError as exc:
            self.stats.refused_moves += 1
            self._emit(str(exc))
            return
        self.stats.moves += 1
        cold = False
        for b in blocks:
            if b.e1 > b.e0 and self.hotend.temp(self.now) < self.min_extrude_temp:
                cold = True
                b.e1 = b.e0
            yield ("slot",)
            b.index = len(self.executed) - 1
            self._push_block(b)
        if cold:
            self.stats.cold_extrusions += 1
            self._emit(COLD)

    def _dwell(self, entry: Entry) -> Generator[Any, None, None]:
        """G4 P<ms> or S<s>, after the planned moves."""
        cmd = entry.cmd
        ms = cmd.value("P", 0.0) or 0.0
        s = cmd.value("S")
        yield ("sync",)
        yield ("time", self.now + (s if s is not None else ms / 1000.0))

    def _home(self, entry: Entry) -> Generator[Any, None, None]:
        yield ("sync",)
        self.motion.home(entry.cmd)
        yield ("time", self.now + self.fw.homing_time)

    def _modes(self, entry: Entry) -> None:
        """G90/G91 (positioning), M82/M83 (extruder), G93/G94 (inverse-time feed, only
        under that feed policy)."""
        code, m = entry.cmd.code, self.motion
        if code in ("G90", "G91"):
            m.relative = code == "G91"
        elif code in ("M82", "M83"):
            m.e_relative = code == "M83"
        elif code == "G93" and m.feed_policy != "inverse-time":
            self._unknown(entry.cmd)
        else:
            m.inverse_time = code == "G93"

    def _set_position(self, entry: Entry) -> None:
        self.motion.set_position(entry.cmd)

    def _sync(self, entry: Entry) -> Generator[Any, None, None]:
        yield ("sync",)

    def _heat_command(self, entry: Entry) -> Generator[Any, None, None]:
        """M104/M109 (hotend) and M140/M190 (bed)."""
        code = entry.cmd.code
        if code in ("M104", "M109"):
            yield from self._heat(entry.cmd, self.hotend, self.fw.hotend_residency,
                                  wait=code == "M109")
        else:
            yield from self._heat(entry.cmd, self.bed, self.fw.bed_residency,
                                  wait=code == "M190")

    def _report(self, entry: Entry) -> None:
        """M105 (temperatures), M114 (position), M115 (capabilities)."""
        code = entry.cmd.code
        if code == "M105":
            self._emit("ok" + self._temp_report())
        elif code == "M114":
            self._emit(self._position_report())
        else:
            for line in self._capabilities():
                self._emit(line)

    def _autoreport_command(self, entry: Entry) -> None:
        """M155 S<s>: report the temperatures every s seconds (0: off)."""
        s = entry.cmd.value("S", 0.0) or 0.0
        self._autoreport = max(s, 0.0)
        self._autoreport_at = self.now + s if s > 0 else math.inf

    def _line_number(self, entry: Entry) -> None:
        # The number was taken when the line was read; a bare M110 N sets it here.
        cmd = entry.cmd
        if entry.n is None and cmd.has_value("N"):
            self.last_n = int(cmd.words["N"])  # type: ignore[arg-type]

    def _limits(self, entry: Entry) -> None:
        """M204 (acceleration), M203 (XY feed limit), M220 (feed percentage), M302 (cold
        extrusion)."""
        cmd, m = entry.cmd, self.motion
        code = cmd.code
        if code == "M204":
            for key in ("S", "P"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.acceleration = float(cmd.words[key])  # type: ignore[arg-type]
        elif code == "M203":
            for key in ("X", "Y"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.max_feed_xy = float(cmd.words[key])  # type: ignore[arg-type]
        elif code == "M220":
            if cmd.has_value("S") and cmd.words["S"] > 0:  # type: ignore[operator]
                m.feed_percent = float(cmd.words["S"])  # type: ignore[arg-type]
        elif cmd.has_value("P"):
            self.min_extrude_temp = 0.0 if cmd.words["P"] else 170.0
        elif cmd.has_value("S"):
            self.min_extrude_temp = float(cmd.words["S"])  # type: ignore[arg-type]

    def _tool(self, entry: Entry) -> None:
        code = entry.cmd.code
        if code != "T0":
            self._emit(f"echo:{code} Invalid extruder")

    def _keepalive(self, entry: Entry) -> None:
        """Marlin's M113: S<s> sets the busy keepalive interval (whole seconds, at most 60;
        S0 turns it off), without S it says the interval."""
        cmd = entry.cmd
        if cmd.has_value("S"):
            v = float(cmd.words["S"])  # type: ignore[arg-type]
            s = 0 if math.isnan(v) else int(min(max(v, 0.0), _M113_MAX))
            self.busy_interval = float(s) if s > 0 else math.inf
        else:
            shown = 0 if math.isinf(self.busy_interval) else round(self.busy_interval)
            self._emit(f"echo:M113 S{shown}")

    def _sd_card(self, entry: Entry) -> None:
        # Marlin's M21 with SDSUPPORT and no card in the slot (CardReader::mount)
        self._emit("echo:No SD card")

    def _heat(self, cmd: Command, heater, residency: float, *, wait: bool):
        """M104/M140 (set) and M109/M190 (``wait``: set, then wait until reached, unless
        S asks only to heat and it is already hot enough) for one heater."""
        target = cmd.value("S", cmd.value("R"))
        if target is not None:
            heater.set(target, self.now)
        if wait and target is not None and target > 0:
            heating_only = cmd.has_value("S")
            if not (heating_only and heater.temp(self.now) >= target):
                t = heater.reach_time(self.now, self.fw.temp_window)
                yield ("time", t + residency, "temp")

    def _unknown(self, cmd: Command) -> None:
        self.stats.unknown += 1
        reply = self.fw.unknown_reply(cmd.text)
        if reply is not None:
            self._emit(reply)

    # ---------------------------------------------------------------- reports
    def _temp_report(self, *, wait: bool = False) -> str:
        return self.fw.temperature_report(self.hotend, self.bed, self.now, wait=wait)

    def _position_report(self) -> str:
        m = self.motion
        lg = m.logical()
        spu = self.fw.steps_per_unit
        names = ["X", "Y", "Z"] + ([m.letter] if m.letter else [])
        pos = " ".join(f"{L}:{lg[i]:.2f}" for i, L in enumerate(names))
        idx = [0, 1, 2, 3][:len(names)]
        counts = " ".join(f"{names[k]}:{round(m.pos[i] * spu[i])}" for k, i in enumerate(idx))
        return f"{pos} E:{m.e:.2f} Count {counts}"

    def _capabilities(self) -> list[str]:
        m = self.motion
        return self.fw.capabilities(self.config.machine, letter=m.letter,
                                    feed_policy=m.feed_policy)


# The handler of each command code (T<n> aside); a code the profile takes as a no-op is not
# looked up, one in neither is unknown.
_HANDLERS: dict[str, Callable[[CommandsMixin, Entry], Iterator[Any] | None]] = {
    **dict.fromkeys(("G0", "G1", "G2", "G3"), CommandsMixin._move),
    "G4": CommandsMixin._dwell,
    "G28": CommandsMixin._home,
    **dict.fromkeys(("G90", "G91", "M82", "M83", "G93", "G94"), CommandsMixin._modes),
    "G92": CommandsMixin._set_position,
    "M400": CommandsMixin._sync,
    **dict.fromkeys(("M104", "M109", "M140", "M190"), CommandsMixin._heat_command),
    **dict.fromkeys(("M105", "M114", "M115"), CommandsMixin._report),
    "M155": CommandsMixin._autoreport_command,
    "M110": CommandsMixin._line_number,
    **dict.fromkeys(("M204", "M203", "M220", "M302"), CommandsMixin._limits),
    "M113": CommandsMixin._keepalive,
    "M21": CommandsMixin._sd_card,
}
