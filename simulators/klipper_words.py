"""The G-code words Klipper drops without a message, found by reading the file as klippy does.

Klipper silently ignores words it has no use for (an unregistered ``C`` on G1, ``G92 C``, a
``C`` on G2/G3...), so a file meant for a rotary axis the printer has not registered still
"runs"; :func:`scan_ignored_words` lists those words, following the axes registered as the
file goes (see :func:`simulators.klipper_batch.run_klipper`).

This module imports nothing from the project (it is a test and benchmark instrument).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = ["IgnoredWord", "scan_ignored_words"]


@dataclass(frozen=True)
class IgnoredWord:
    """A G-code word Klipper drops without a message.

    Attributes
    ----------
    line : int
        1-based line number in the file.
    command : str
        The command the word was on (``G1``, ``G92``...).
    word : str
        The word as Klipper parsed it (letter and value, upper case), e.g. ``C45``.
    reason : str
        Why Klipper ignores it.
    """

    line: int
    command: str
    word: str
    reason: str


# klippy's own tokeniser (gcode.py GCodeDispatch.args_r): the upper-cased line, up to ';',
# split into a command and letter/value pairs
_ARGS_R = re.compile(r"([A-Z_]+|[A-Z*])")
_AXIS_REG_R = re.compile(r"^\s*(?:N\d+\s+)?MANUAL_STEPPER\b(.*)$", re.IGNORECASE)
_GCODE_AXIS_R = re.compile(r"\bGCODE_AXIS=(\S*)", re.IGNORECASE)
_STEPPER_R = re.compile(r"\bSTEPPER=(\S+)", re.IGNORECASE)
# a cheap filter: only lines that may hold a motion command are tokenised
_MOTION_R = re.compile(rb"^\s*(?:N\d+\s*)?G\s*(?:[0-4]|28|92)(?![0-9.])", re.IGNORECASE)


def _klippy_parse(line: str) -> tuple[str, list[tuple[str, str]]]:
    """Command and (letter, value) words, as klippy's GCodeDispatch splits a line."""
    cpos = line.find(";")
    if cpos >= 0:
        line = line[:cpos]
    parts = _ARGS_R.split(line.strip().upper())
    if "".join(parts[:2]) == "N":
        cmd = "".join(parts[3:5]).strip()
        words = [(parts[i], parts[i + 1].strip()) for i in range(5, len(parts) - 1, 2)]
    else:
        cmd = "".join(parts[:3]).strip()
        words = [(parts[i], parts[i + 1].strip()) for i in range(3, len(parts) - 1, 2)]
    return cmd, words


def scan_ignored_words(lines: Iterable[str | bytes], *, axes: str = "XYZE",
                       axis_changes: Sequence[tuple[int, str]] | None = None,
                       ) -> list[IgnoredWord]:
    """Words of motion commands that Klipper drops without a message.

    Klipper reads from G0/G1 only X, Y, Z, E, F and the letters registered as extra axes; from
    G2/G3 (``[gcode_arcs]``) X, Y, Z, I, J (K in the G18/G19 planes), E, F (an R is an error it
    reports); from G92 only X, Y, Z, E (never an extra axis); from G28 only X, Y, Z (``G28 C``
    homes all axes); from G4 only P (Marlin's ``G4 S30``, seconds, is a dwell of 0). Anything
    else on those commands is silently ignored, which is why a file meant for a rotary axis
    that the printer has not registered still "runs".

    Parameters
    ----------
    lines : iterable of str or bytes
        The file's lines, in order (line 1 first).
    axes : str
        Letters registered when the file starts (``XYZE`` plus extra axes).
    axis_changes : sequence of (int, str) or None
        The registered letters as klippy changed them: ``(line, letters)`` means ``letters``
        from the line after ``line`` on (:func:`run_klipper` passes what klippy did, macros
        included). None: follow the file's own ``MANUAL_STEPPER ... GCODE_AXIS=`` lines.

    Returns
    -------
    list of IgnoredWord
    """
    registered = {a.upper() for a in axes}
    by_stepper: dict[str, str] = {}

    def register(rest: str) -> None:
        m, s = _GCODE_AXIS_R.search(rest), _STEPPER_R.search(rest)
        if m is None or s is None:
            return
        letter, stepper = m.group(1).upper(), s.group(1).lower()
        if letter:
            by_stepper[stepper] = letter
            registered.add(letter)
        elif stepper in by_stepper:      # GCODE_AXIS= (empty) unregisters
            registered.discard(by_stepper.pop(stepper))

    changes = sorted(axis_changes or ())
    k = 0
    plane = "G17"
    found: list[IgnoredWord] = []
    for n, raw in enumerate(lines, 1):
        while k < len(changes) and changes[k][0] < n:
            registered = set(changes[k][1].upper())
            k += 1
        b = raw if isinstance(raw, bytes) else raw.encode("utf-8", "replace")
        if not _MOTION_R.match(b):
            if axis_changes is None and b"MANUAL_STEPPER" in b.upper():
                m = _AXIS_REG_R.match(b.decode("utf-8", "replace"))
                if m is not None:
                    register(m.group(1))
            elif b.lstrip()[:2].upper() == b"G1" and b.lstrip()[2:3] in (b"7", b"8", b"9"):
                plane = b.lstrip()[:3].decode().upper()
            continue
        cmd, words = _klippy_parse(b.decode("utf-8", "replace"))
        if cmd in ("G0", "G1"):
            allowed, why = registered | {"F"}, "not a registered axis (G0/G1 reads X Y Z E F "
            why += "and registered extra axes)"
        elif cmd in ("G2", "G3"):
            allowed = {"X", "Y", "Z", "I", "J", "E", "F", "R"}
            if plane != "G17":
                allowed.add("K")
            why = f"G2/G3 reads only X Y Z I J{' K' if plane != 'G17' else ''} E F"
        elif cmd == "G92":
            allowed, why = {"X", "Y", "Z", "E"}, "G92 sets only X Y Z E"
        elif cmd == "G28":
            allowed, why = {"X", "Y", "Z"}, "G28 homes only X Y Z"
        elif cmd == "G4":
            allowed, why = {"P"}, "G4 reads only P (milliseconds)"
        else:
            continue
        for letter, value in words:
            if letter not in allowed and letter != "*":
                found.append(IgnoredWord(n, cmd, letter + value, why))
    return found
