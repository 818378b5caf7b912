"""Rewriting the address words of one existing G-code line, keeping every other byte.

What the post-processor uses (:func:`edit_line`, re-exported by :mod:`gcode.writer`): a
word replaced, added or dropped; spacing, comment and line terminator stay as they were. Lines
of the shape slicers write nearly every move in are edited by slicing their bytes
(:data:`SIMPLE_MOVE`); any other line goes through the lossless tokeniser
(:func:`gcode.line.parse_line`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gcode.line import ParsedLine

__all__ = ["SIMPLE_MOVE", "edit_e", "edit_line", "edit_tokens", "simple_move_words"]

# The shape slicers write nearly every move in: "G1 X1.5 Y-2 E.03 F1800 ; note\n" (upper-case
# letters, signed decimals with a digit after any point, words set off by spaces; no line
# number, checksum, tab between words or quote). parse_line splits such a line into command,
# words, trailing blanks, comment and terminator and nothing else, so words can be found and
# edited by slicing the bytes; every other line goes through the lossless tokeniser.
SIMPLE_MOVE = re.compile(
    # one way to match each number: no backtracking blow-up on long lines that fail
    rb"G\d+((?: +[A-Z][-+]?(?:\d+(?:\.\d+)?|\.\d+))*)[ \t]*(?:;[^\r\n]*)?(?:\r\n|\n|\r)?\Z")


def simple_move_words(raw: bytes) -> list[bytes] | None:
    """The address words of a line in the common slicer shape, or None for any other line.

    Parameters
    ----------
    raw
        The line, with or without its terminator.

    Returns
    -------
    list of bytes or None
        The words as written (``[b"X1.5", b"E.03"]``), the same as the ``text`` of
        :attr:`gcode.line.ParsedLine.words`; None when the line is not a ``G`` command
        of upper-case letter-number words separated by spaces (then use
        :func:`gcode.line.parse_line`).
    """
    m = SIMPLE_MOVE.match(raw)
    if m is None:
        return None
    return raw[m.start(1):m.end(1)].split()


def edit_e(raw: bytes, new_e: Callable[[float], str], *,
           add: Sequence[str] = ()) -> tuple[bytes, float] | None:
    """Replace the E word of a line of the common slicer shape, in one pass over it.

    Parameters
    ----------
    raw
        The line, with its terminator.
    new_e
        The new value's text (without the letter), from the value the line has.
    add
        Words appended as :func:`edit_line` appends them.

    Returns
    -------
    (bytes, float) or None
        The new line (what ``edit_line(raw, replace={"E": "E" + new_e(v)}, add=add)``
        gives) and the value ``v`` the line had; None when the line is not of the common
        shape or has no E word (use :func:`edit_line`).
    """
    m = SIMPLE_MOVE.match(raw)
    if m is None:
        return None
    a, b = m.span(1)
    parts = raw[a:b].split(b" ")
    for i, part in enumerate(parts):
        if part[:1] == b"E":
            value = float(part[1:])
            parts[i] = b"E" + new_e(value).encode("ascii")
            return _assemble(raw, a, b, parts, add), value
    return None


def _assemble(raw: bytes, a: int, b: int, parts: list[bytes] | None,
              extra: Sequence[str]) -> bytes:
    """The line with its words ``raw[a:b]`` replaced by ``parts`` joined on single blanks
    (None: kept) and the ``extra`` words appended after them."""
    head = raw[:b] if parts is None else raw[:a] + b" ".join(parts)
    if not extra:
        return head + raw[b:]
    return head + b" " + b" ".join(w.encode("ascii") for w in extra) + raw[b:]


def _edit_simple(raw: bytes, replace: Mapping[str, str] | None,
                 add: Sequence[str]) -> bytes | None:
    """:func:`edit_line` without ``drop`` on a line of the common shape; None for other lines."""
    m = SIMPLE_MOVE.match(raw)
    if m is None:
        return None
    a, b = m.span(1)
    parts = None
    todo = dict(replace) if replace else {}
    if todo and a < b:
        # split on single spaces so that runs of blanks come back unchanged from the join
        parts = raw[a:b].split(b" ")
        for i, part in enumerate(parts):
            if part and chr(part[0]) in todo:
                parts[i] = todo.pop(chr(part[0])).encode("ascii")
                if not todo:
                    break
    return _assemble(raw, a, b, parts, [*todo.values(), *add])


def edit_line(raw: bytes, *, replace: Mapping[str, str] | None = None,
              add: Sequence[str] = (), drop: Sequence[str] = ()) -> bytes:
    """Rewrite the address words of one line, keeping every other byte.

    Parameters
    ----------
    raw
        The line, with its terminator.
    replace
        Letter → new word text (``{"E": "E0.01234"}``): the first word with
        that letter is replaced in place.
    add
        Words inserted after the last address word (``["C12.5"]``), each
        preceded by one space.
    drop
        Letters whose first word is removed (with the blank before it).

    Returns
    -------
    bytes
        The new line. A word to replace that the line lacks is added instead.
    """
    if not drop and isinstance(raw, bytes):
        fast = _edit_simple(raw, replace, add)
        if fast is not None:
            return fast
    from gcode.line import parse_line

    return edit_tokens(parse_line(raw), replace=replace, add=add, drop=drop)


def edit_tokens(parsed: ParsedLine, *, replace: Mapping[str, str] | None = None,
                add: Sequence[str] = (), drop: Sequence[str] = ()) -> bytes:
    """:func:`edit_line` on a line already split by :func:`gcode.line.parse_line` (any line)."""
    from gcode.line import Segment

    segs = list(parsed.segments)
    todo = dict(replace or {})
    dropping = {d.upper() for d in drop}
    last_word = None
    out: list[Segment] = []
    for seg in segs:
        if seg.kind == "word" and seg.text[:1].isalpha():
            letter = seg.text[:1].decode("ascii").upper()
            if letter in dropping:
                dropping.discard(letter)
                if out and out[-1].kind == "ws":
                    out.pop()
                continue
            if letter in todo:
                seg = Segment("word", todo.pop(letter).encode("ascii"))
        out.append(seg)
        if seg.kind in ("word", "command", "number"):
            last_word = len(out)
    extra = [*todo.values(), *add]
    if extra:
        insert = [Segment("ws", b" "), *(s for w in extra
                                         for s in (Segment("word", w.encode("ascii")),
                                                   Segment("ws", b" ")))][:-1]
        pos = last_word if last_word is not None else 0
        out[pos:pos] = insert
    return b"".join(s.text for s in out)
