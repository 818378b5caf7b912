"""The modal state the firmware has after some line of a program, and how to restore it.

:class:`MachineState` follows positions (the rotary axes and E included),
absolute/relative modes, feed rate, temperatures and fan, command by command;
:func:`state_at` runs a program's first commands through it, and
:func:`restore_commands` brings a restarted printer back to such a state, so
that a print can be resumed after a lost connection.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from machine_io.protocol import EXTRA_AXES, command_code

if TYPE_CHECKING:
    from machine_io.program import Program

__all__ = ["MachineState", "command_words", "restore_commands", "state_at"]

_WORD = re.compile(r"([A-Za-z])\s*([+-]?(?:\d+\.?\d*|\.\d+))")
_HEATING_WAITS = {"M109": "T", "M190": "B", "M191": "C"}
_HEATING_SETS = {"M104": "T", "M140": "B", "M141": "C"}


def command_words(text: str) -> dict[str, float]:
    """The words of a command after its code, letter (upper case) to value: ``G1 X1 y2``
    gives ``{"X": 1.0, "Y": 2.0}``."""
    out: dict[str, float] = {}
    code_end = 0
    m = re.match(r"\s*[GMTgmt]\d+(?:\.\d+)?", text)
    if m:
        code_end = m.end()
    for letter, value in _WORD.findall(text[code_end:]):
        out[letter.upper()] = float(value)
    return out


@dataclass(frozen=True)
class MachineState:
    """Modal state of the firmware after some line of a program.

    Attributes
    ----------
    position
        Logical position of each axis (X, Y, Z, rotary axes, E), mm or degrees,
        in the file's coordinates (after any G92 it issued).
    absolute
        G90 (True) or G91 (False) for X, Y, Z and rotary axes.
    e_absolute
        M82 (True) or M83 (False).
    feed
        Last F, mm/min (None before any).
    temperatures
        Last targets set: ``{"T": 210.0, "B": 60.0}``, °C.
    fan
        Last part-fan speed 0–255 (M106/M107), None before any.
    inches
        G20 in effect.
    tool
        Active tool number.
    """

    position: dict[str, float] = field(default_factory=dict)
    absolute: bool = True
    e_absolute: bool = True
    feed: float | None = None
    temperatures: dict[str, float] = field(default_factory=dict)
    fan: int | None = None
    inches: bool = False
    tool: int = 0

    def apply(self, command: str) -> MachineState:
        """The state after ``command`` (a new object; this one is unchanged)."""
        code = command_code(command)
        if not code:
            return self
        if code in ("G0", "G1", "G2", "G3", "G92"):
            words = command_words(command)
            pos = dict(self.position)
            for letter, value in words.items():
                if letter in "FIJKRPS":
                    continue
                if code == "G92":
                    pos[letter] = value
                elif letter == "E":
                    pos["E"] = value if self.e_absolute else pos.get("E", 0.0) + value
                elif letter in "XYZ" or letter in EXTRA_AXES:
                    pos[letter] = value if self.absolute else pos.get(letter, 0.0) + value
            if code == "G92" and not words:
                pos = {k: 0.0 for k in pos} | {k: 0.0 for k in "XYZE"}
            feed = words.get("F", self.feed) if code != "G92" else self.feed
            return replace(self, position=pos, feed=feed)
        if code == "G90":
            return replace(self, absolute=True, e_absolute=True)
        if code == "G91":
            return replace(self, absolute=False, e_absolute=False)
        if code == "M82":
            return replace(self, e_absolute=True)
        if code == "M83":
            return replace(self, e_absolute=False)
        if code in ("G20", "G21"):
            return replace(self, inches=code == "G20")
        if code in _HEATING_SETS or code in _HEATING_WAITS:
            words = command_words(command)
            target = words.get("S", words.get("R"))
            if target is None:
                return self
            key = _HEATING_SETS.get(code) or _HEATING_WAITS[code]
            if key == "T" and "T" in words:
                key = f"T{int(words['T'])}"
            return replace(self, temperatures=self.temperatures | {key: target})
        if code == "M106":
            return replace(self, fan=int(command_words(command).get("S", 255)))
        if code == "M107":
            return replace(self, fan=0)
        if code[0] == "T" and code[1:].isdigit():
            return replace(self, tool=int(code[1:]))
        return self


def state_at(program: Program, index: int) -> MachineState:
    """The modal state after the first ``index`` commands of ``program`` have run."""
    state = MachineState()
    for command in itertools.islice(program.commands, index):
        state = state.apply(command)
    return state


def restore_commands(state: MachineState, *, home_xy: bool, lift: float = 2.0,
                     travel_feed: float = 3000.0) -> tuple[str, ...]:
    """Commands that bring a freshly restarted printer back to ``state``.

    Heats (set both, then wait, so bed and hotend heat together), declares Z,
    the rotary angle and E where they were (the part is on the bed: Z cannot
    be homed; a nozzle turned by a stepper keeps its angle through a reset),
    lifts, homes X and Y if asked, travels back, lowers, then restores the
    modes and the feed rate.

    Parameters
    ----------
    state
        The state to restore (see :func:`state_at`).
    home_xy
        Home X and Y first (the firmware restarted and lost its position).
    lift
        Z clearance for the travel back, mm.
    travel_feed
        Travel feed rate, mm/min.
    """
    out: list[str] = []
    temps = state.temperatures
    for key, value in temps.items():
        if key == "B":
            out.append(f"M140 S{value:g}")
        elif key == "C":
            out.append(f"M141 S{value:g}")
        else:
            out.append(f"M104 {'' if key == 'T' else 'T' + key[1:] + ' '}S{value:g}")
    if "B" in temps:  # the bed is slowest: wait for it first
        out.append(f"M190 S{temps['B']:g}")
    for key, value in temps.items():
        if key[0] == "T":
            out.append(f"M109 {'' if key == 'T' else 'T' + key[1:] + ' '}S{value:g}")
    if state.inches:
        out.append("G20")
    pos = state.position
    out.append("G90")
    declare = [f"{k}{pos[k]:.4f}" for k in ("Z", *sorted(EXTRA_AXES)) if k in pos]
    if declare:
        out.append("G92 " + " ".join(declare))
    if "Z" in pos:
        out.append(f"G1 Z{pos['Z'] + lift:.4f} F600")
    if home_xy:
        out.append("G28 X Y")
    xy = [f"{k}{pos[k]:.4f}" for k in ("X", "Y") if k in pos]
    if xy:
        out.append(f"G1 {' '.join(xy)} F{travel_feed:g}")
    if "Z" in pos:
        out.append(f"G1 Z{pos['Z']:.4f} F600")
    out.append(f"G92 E{pos.get('E', 0.0):.5f}")
    out.append("M82" if state.e_absolute else "M83")
    if not state.absolute:
        out.append("G91")
    if state.fan is not None:
        out.append(f"M106 S{state.fan}")
    if state.feed is not None:
        out.append(f"G1 F{state.feed:g}")
    return tuple(out)
