"""Command parsing inside the simulated firmware.

The words of a command are read with pygcode (the design card's independent
parser, docs/design.md §6) so that the simulator cross-checks the project's own
reader in ``gcode/``. pygcode models CNC G-code and refuses several things a
3-D printer firmware accepts; those are handled here the way Marlin's
``GCodeParser`` does:

- ``;`` comments are stripped before parsing (Marlin ignores the rest of the
  line; parentheses are *not* comments in a default Marlin build);
- valueless words (``M84 X Y E``) and invalid numbers (``X--1``): Marlin marks
  the letter as seen without a value (``parser.seen('X')`` true,
  ``parser.seenval('X')`` false) and skips to the next space;
- string arguments (``M117 Hello``, ``M118``, ``M23 file``...) keep the raw rest
  of the line;
- anything whose first word is not ``G<n>``/``M<n>``/``T<n>`` (a Klipper macro
  such as ``START_PRINT EXTRUDER_TEMP=200``) is an unknown command, reported by
  the caller as ``echo:Unknown command: "…"``.

Speed: pygcode's word reader runs at ~60 k lines/s here, well above what a
115200-baud wire delivers (~450 lines/s), so it is used on every line; a small
cache short-cuts the many identical lines of real files (``G92 E0``, fan and
retraction moves), which firmware semantics allow because parsing has no side
effect.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from pygcode.exceptions import GCodeWordStrError
from pygcode.words import text2words

__all__ = ["Command", "parse_command", "strip_comment"]

# M-codes whose parameter is free text (Marlin: parser.string_arg).
_STRING_ARG = frozenset({"M0", "M1", "M16", "M23", "M28", "M30", "M32", "M33", "M117", "M118",
                         "M928"})
_HEAD = re.compile(r"\s*([GMTgmt])\s*([+-]?\d+(?:\.\d+)?)")
# Marlin's valid_number(): optional sign, then a digit or '.' followed by a digit.
_NUM = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_CACHE_MAX = 4096
_MOVES = frozenset({"G0", "G1", "G2", "G3"})


@dataclass(frozen=True)
class Command:
    """One parsed firmware command.

    Attributes
    ----------
    code
        ``"G1"``, ``"M104"``, ``"T0"``... or ``""`` when the line is not a
        G/M/T command (unknown command, macro).
    words
        Parameter letters (upper case) to values; ``None`` for a letter seen
        without a valid value.
    text
        The command as executed (comment and surrounding spaces removed).
    string_arg
        Raw text after the code for string-argument commands.
    parsed_by
        ``"pygcode"`` or ``"firmware"`` (the fallback tokenizer).
    """

    code: str
    words: dict[str, float | None] = field(default_factory=dict)
    text: str = ""
    string_arg: str = ""
    parsed_by: str = "pygcode"

    def value(self, letter: str, default: float | None = None) -> float | None:
        v = self.words.get(letter)
        return default if v is None else v

    def has_value(self, letter: str) -> bool:
        return self.words.get(letter) is not None


def strip_comment(text: str) -> str:
    """Drop a ``;`` comment and surrounding whitespace (Marlin's serial reader)."""
    i = text.find(";")
    return (text if i < 0 else text[:i]).strip()


def _firmware_words(rest: str) -> dict[str, float | None]:
    """Marlin-style tokenizer: letter, optional spaces, a number if valid."""
    words: dict[str, float | None] = {}
    i, n = 0, len(rest)
    while i < n:
        c = rest[i]
        if c.isalpha() and c.isascii():
            j = i + 1
            while j < n and rest[j] == " ":
                j += 1
            m = _NUM.match(rest, j)
            letter = c.upper()
            if m:
                try:
                    words[letter] = float(m.group())
                except ValueError:  # pragma: no cover - regex guarantees a float
                    words[letter] = None
                i = m.end()
            else:
                words.setdefault(letter, None)
                i = j
                if i < n and not rest[i].isalpha():
                    while i < n and rest[i] != " ":  # skip the invalid value
                        i += 1
        else:
            i += 1
    return words


_cache: dict[str, Command] = {}


def parse_command(text: str) -> Command:
    """Parse one command line (line number and checksum already removed).

    Parameters
    ----------
    text
        The line, possibly with a ``;`` comment.

    Returns
    -------
    Command
        ``code == ""`` for a line the firmware does not recognise as G/M/T.
    """
    hit = _cache.get(text)
    if hit is not None:
        return hit
    body = strip_comment(text)
    m = _HEAD.match(body)
    if not m:
        cmd = Command("", {}, body, body, "firmware")
    else:
        letter, num = m.group(1).upper(), m.group(2)
        try:
            n = float(num)
        except ValueError:  # pragma: no cover
            n = -1.0
        code = f"{letter}{int(n)}" if n == int(n) else f"{letter}{num}"
        rest = body[m.end():]
        if code in _STRING_ARG:
            cmd = Command(code, {}, body, rest.strip(), "firmware")
        else:
            try:
                words: dict[str, float | None] = {}
                for w in text2words(rest):
                    words[w.letter.upper()] = float(w.value)
                cmd = Command(code, words, body, rest.strip(), "pygcode")
            except (GCodeWordStrError, ValueError, TypeError, AttributeError):
                cmd = Command(code, _firmware_words(rest), body, rest.strip(), "firmware")
    # Moves are nearly all distinct; caching them would only evict the repeats.
    if cmd.code not in _MOVES and len(_cache) < _CACHE_MAX:
        _cache[text] = cmd
    return cmd
