"""What a file says before it is parsed: whether printability already post-processed it (its
marker comment, or a binary file's print metadata), and numbers from the slicer's
configuration comments."""

from __future__ import annotations

import re

from gcode.bgcode import BinaryGCode, decode_bgcode, is_bgcode
from printability.errors import FileFormatError

#: Print-metadata key that marks a binary file whose G-code encoding drops comments
#: (MeatPack without comments), where the comment block cannot say it was post-processed
PROCESSED_KEY = "postprocessed by"

_PROCESSED = re.compile(rb"; printability \S+ postprocessed this file")


def already_processed(data: bytes) -> bool:
    """True when printability's marker comment is in the file (binary G-code: in its G-code,
    or its print metadata say so)."""
    if is_bgcode(data):
        try:
            return binary_processed(decode_bgcode(data))
        except FileFormatError:
            return False
    return _first_at_line_start(data, b"; printability ", _PROCESSED) is not None


def binary_processed(doc: BinaryGCode) -> bool:
    """True when a decoded binary file's print metadata or its G-code say printability
    post-processed it."""
    marked = doc.value(PROCESSED_KEY)
    return (marked is not None and marked.startswith("printability")) or \
        already_processed(doc.gcode)


_BLANK = frozenset(b" \t\n\r\x0b\x0c")  # what \s matches in a bytes pattern


def _first_at_line_start(data: bytes, word: bytes, pattern: re.Pattern, *,
                         comment: bool = False) -> re.Match | None:
    """The first match of ``pattern`` at a line start (``re.search`` with ``^`` and
    ``re.MULTILINE``), for a pattern that is ``word`` and more (``comment``: ``;``, blanks,
    then ``word`` and more).

    The occurrences of ``word`` are found with ``bytes.find`` (a scan in C) and the pattern
    is tried only at the line start before each: a regular-expression scan tries every
    position of the file (tens of ms on a 3 MB file). A match's start is determined by its
    ``word``, and moves on with it, so the first occurrence that matches gives the first
    match.
    """
    pos = data.find(word)
    while pos >= 0:
        s = pos
        if comment:
            s -= 1
            while s >= 0 and data[s] in _BLANK:
                s -= 1
            ok = s >= 0 and data[s] == 59  # ";"
        else:
            ok = True
        if ok and (s == 0 or data[s - 1] == 10):
            m = pattern.match(data, s)
            if m is not None:
                return m
        pos = data.find(word, pos + 1)
    return None


def config_value(data: bytes, key: str) -> float | None:
    """A number from the slicer's configuration comments (``; key = value``)."""
    kb = key.encode()
    m = _first_at_line_start(data, kb, re.compile(rb";\s*" + re.escape(kb)
                                                  + rb"\s*=\s*([-+0-9.eE]+)"), comment=True)
    if not m:
        return None
    try:
        return float(m.group(1))
    except ValueError:
        return None
