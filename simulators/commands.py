"""What each command does: moves, dwells, homing, heaters, modes, and the reports.

One generator per G/M-code (:meth:`CommandsMixin._run`) yields what it waits
for (see :mod:`simulators.planner`); the M105, M114 and M115 reports are
formatted here. Also the first-order :class:`Heater` the temperature
commands drive. Mixed into :class:`simulators.firmware.Firmware`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Generator
from typing import Any

from simulators.kinematics import MotionError
from simulators.line_protocol import _Entry
from simulators.parsing import Command

__all__ = ["CommandsMixin", "Heater"]

COLD = "echo: cold extrusion prevented"

# Commands the firmware accepts and (for the simulation) need no effect.
_NOOP = frozenset({
    "M17", "M18", "M84", "M106", "M107", "M73", "M75", "M76", "M77", "M117", "M118", "M201",
    "M205", "M221", "M500", "M501", "M502", "M503", "M900", "M907", "M92", "M80", "M81",
    "M111", "M119", "M31", "M42", "M420", "M149", "M851", "M593", "M486", "M999", "G21",
    "G29", "G10", "G11", "M0", "M1", "M16", "M23", "M24", "M25", "M27", "M28", "M29", "M30",
    "M32", "M33", "M928", "M413", "M163", "M164", "M141", "M191", "M150", "M600",
    # M108 (break a heating wait: the host's cancel sends it raw; the emergency parser acts on
    # it); Marlin's M113 and M21 are answered in CommandsMixin._run (Klipper takes them as
    # no-ops here too)
    "M108",
})
_KLIPPER_NOOP = frozenset({"M113", "M21"})
# Marlin's M113 (HOST_KEEPALIVE_FEATURE) caps the interval at 60 s (gcode/host/M113.cpp)
_M113_MAX = 60
_KLIPPER_MACROS = re.compile(r"^[A-Z][A-Z0-9]*_[A-Z0-9_]+\b|^(?:PAUSE|RESUME|CANCEL_PRINT|"
                             r"STATUS|RESTART|FIRMWARE_RESTART|SAVE_CONFIG)\b", re.IGNORECASE)


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
    def _run(self, entry: _Entry) -> Generator[Any, None, None]:
        cmd = entry.cmd
        code = cmd.code
        m = self.motion
        if code in ("G0", "G1", "G2", "G3"):
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
            return
        if code == "G4":
            ms = cmd.value("P", 0.0) or 0.0
            s = cmd.value("S")
            yield ("sync",)
            yield ("time", self.now + (s if s is not None else ms / 1000.0))
            return
        if code == "G28":
            yield ("sync",)
            m.home(cmd)
            yield ("time", self.now + self.fw.homing_time)
            return
        if code in ("G90", "G91"):
            m.relative = code == "G91"
            return
        if code in ("M82", "M83"):
            m.e_relative = code == "M83"
            return
        if code == "G92":
            m.set_position(cmd)
            return
        if code in ("G93", "G94"):
            if code == "G93" and m.feed_policy != "inverse-time":
                self._unknown(cmd)
            else:
                m.inverse_time = code == "G93"
            return
        if code == "M400":
            yield ("sync",)
            return
        if code in ("M104", "M109"):
            yield from self._heat(cmd, self.hotend, self.fw.hotend_residency, wait=code == "M109")
            return
        if code in ("M140", "M190"):
            yield from self._heat(cmd, self.bed, self.fw.bed_residency, wait=code == "M190")
            return
        if code == "M105":
            self._emit("ok" + self._temp_report())
            return
        if code == "M155":
            s = cmd.value("S", 0.0) or 0.0
            self._autoreport = max(s, 0.0)
            self._autoreport_at = self.now + s if s > 0 else math.inf
            return
        if code == "M110":
            # The number was taken when the line was read; a bare M110 N sets it here.
            if entry.n is None and cmd.has_value("N"):
                self.last_n = int(cmd.words["N"])  # type: ignore[arg-type]
            return
        if code == "M114":
            self._emit(self._position_report())
            return
        if code == "M115":
            for line in self._capabilities():
                self._emit(line)
            return
        if code == "M204":
            for key in ("S", "P"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.acceleration = float(cmd.words[key])  # type: ignore[arg-type]
            return
        if code == "M203":
            for key in ("X", "Y"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.max_feed_xy = float(cmd.words[key])  # type: ignore[arg-type]
            return
        if code == "M220":
            if cmd.has_value("S") and cmd.words["S"] > 0:  # type: ignore[operator]
                m.feed_percent = float(cmd.words["S"])  # type: ignore[arg-type]
            return
        if code == "M302":
            if cmd.has_value("P"):
                self.min_extrude_temp = 0.0 if cmd.words["P"] else 170.0
            elif cmd.has_value("S"):
                self.min_extrude_temp = float(cmd.words["S"])  # type: ignore[arg-type]
            return
        if code.startswith("T"):
            if code != "T0":
                self._emit(f"echo:{code} Invalid extruder")
            return
        if code == "M113" and self.fw.name != "klipper":
            # Marlin: S<s> sets the busy keepalive interval (whole seconds, at most 60; S0
            # turns it off), without S it says the interval
            if cmd.has_value("S"):
                v = float(cmd.words["S"])  # type: ignore[arg-type]
                s = 0 if math.isnan(v) else int(min(max(v, 0.0), _M113_MAX))
                self.busy_interval = float(s) if s > 0 else math.inf
            else:
                shown = 0 if math.isinf(self.busy_interval) else round(self.busy_interval)
                self._emit(f"echo:M113 S{shown}")
            return
        if code == "M21" and self.fw.name != "klipper":
            # Marlin with SDSUPPORT and no card in the slot (CardReader::mount)
            self._emit("echo:No SD card")
            return
        if code in _NOOP or (code in _KLIPPER_NOOP and self.fw.name == "klipper"):
            return
        self._unknown(cmd)

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
        if self.fw.name == "klipper":
            if _KLIPPER_MACROS.match(cmd.text):
                return  # an extended command (macro): accepted
            self._emit(self.fw.unknown_format.format(cmd.text.split(" ")[0].upper()))
            return
        self._emit(self.fw.unknown_format.format(cmd.text))

    # ---------------------------------------------------------------- reports
    def _temp_report(self, *, wait: bool = False) -> str:
        t = self.now
        h, b = self.hotend, self.bed
        if self.fw.name == "klipper":
            return f" B:{b.temp(t):.1f} /{b.target:.1f} T0:{h.temp(t):.1f} /{h.target:.1f}"
        text = (f" T:{h.temp(t):.2f} /{h.target:.2f} B:{b.temp(t):.2f} /{b.target:.2f} "
                f"@:{h.power(t)} B@:{b.power(t)}")
        if wait:
            text += " W:?"
        return text

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
        if self.fw.name == "klipper":
            return [f"FIRMWARE_NAME:Klipper FIRMWARE_VERSION:{self.fw.firmware_name}"]
        axes = 4 if m.letter else 3
        mc = self.config.machine
        lines = [f"FIRMWARE_NAME:{self.fw.firmware_name} SOURCE_CODE_URL:github.com/"
                 f"MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:{mc.name} "
                 f"KINEMATICS:Cartesian EXTRUDER_COUNT:1 AXIS_COUNT:{axes}"]
        caps = [("SERIAL_XON_XOFF", 0), ("BINARY_FILE_TRANSFER", 0), ("EEPROM", 0),
                ("VOLUMETRIC", 1), ("AUTOREPORT_POS", 0), ("AUTOREPORT_TEMP", 1),
                ("PROGRESS", 0), ("PRINT_JOB", 1), ("AUTOLEVEL", 0), ("RUNOUT", 0),
                ("Z_PROBE", 0), ("LEVELING_DATA", 0), ("BUILD_PERCENT", 0),
                ("SOFTWARE_POWER", 0), ("TOGGLE_LIGHTS", 0), ("CASE_LIGHT_BRIGHTNESS", 0),
                ("EMERGENCY_PARSER", 1), ("HOST_ACTION_COMMANDS", 0), ("PROMPT_SUPPORT", 0),
                ("SDCARD", 1), ("REPEAT", 0), ("SD_WRITE", 0), ("AUTOREPORT_SD_STATUS", 0),
                ("LONG_FILENAME", 0), ("EXTENDED_M20", 0), ("THERMAL_PROTECTION", 1),
                ("MOTION_MODES", 0), ("ARCS", 1), ("BABYSTEPPING", 0),
                ("CHAMBER_TEMPERATURE", 0), ("COOLER_TEMPERATURE", 0), ("MEATPACK", 0),
                ("CONFIG_EXPORT", 0), ("ADVANCED_OK", int(self.fw.advanced_ok))]
        lines += [f"Cap:{k}:{v}" for k, v in caps]
        if m.letter:
            lo = "none" if mc.full_turn else f"{mc.angle_min:g}"
            hi = "none" if mc.full_turn else f"{mc.angle_max:g}"
            lines.append(f"Cap:ROTARY_AXIS:{m.letter}")
            lines.append(f"echo:Rotary axis {m.letter} (deg) min:{lo} max:{hi} "
                         f"feed_policy:{m.feed_policy}")
        return lines
