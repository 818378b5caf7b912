"""One G-code line as a lossless token stream (pure Python, regex based).

:func:`parse_line` splits a raw line (``bytes``, with its terminator) into
typed segments that partition it exactly, so ``ParsedLine.to_bytes()`` gives
back the input byte for byte, including odd spacing, lower-case letters,
``N…*cs`` framing, quoted strings, free-text arguments, comments with bytes
that are not UTF-8, and the line terminator.

Segment kinds:

``bom``       a UTF-8 byte-order mark at the start of the line
``ws``        blanks (spaces, tabs) between tokens
``number``    the ``N123`` line number
``command``   ``G1``, ``M862.3``, ``T0`` or a named (Klipper) command ``EXCLUDE_OBJECT_DEFINE``
``word``      an address word: letter plus number (``X-1.5``), letter alone (``X`` of
              ``M84 X Y E``) or letter plus quoted string (``P"MK3S"``)
``string``    a bare quoted string (``M862.3 P "MK3S"``)
``text``      free text: the argument of ``M117``-like commands and of named commands
``bad``       bytes that are not a valid token (the line is then flagged)
``checksum``  ``*123``
``comment``   from ``;`` to the end of the content
``eol``       the terminator: ``\\n``, ``\\r\\n``, ``\\r`` or nothing on a last line

This is the readable, independent twin of the whole-file tokeniser in
:mod:`gcode._lexer`; the tests require both to agree on every line of the
sample files and on random lines. The writer rewrites a line by replacing
some ``word`` segments and keeping all others.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gcode._lexer import STRING_ARG_MCODES

__all__ = ["ParsedLine", "Segment", "Word", "extended_params", "parse_line"]

_NUMWORD = re.compile(rb"[A-Za-z]([+-]?)(\d*)(?:(\.)(\d*))?")
_QUOTED = re.compile(rb'"(?:[^"]|"")*"?')
_NWORD = re.compile(rb"[Nn](\d+)(?=[ \t*]|$)")
_CMD = re.compile(rb"([GgMmTt])(\d+)(?:\.(\d+))?")
_IDENT = re.compile(rb"[A-Za-z][A-Za-z_][A-Za-z0-9_]*")
_BLANKS = re.compile(rb"[ \t]*")
_NONBLANK = re.compile(rb"[^ \t]*")
_CHECKSUM = re.compile(rb"\*(\d+)$")
_CONTROL = re.compile(rb"[\x00-\x08\x0a-\x1f\x7f]")


@dataclass(frozen=True)
class Segment:
    """A typed slice of a line: ``kind`` (see module docs) and its exact ``text``."""

    kind: str
    text: bytes


@dataclass(frozen=True)
class Word:
    """An address word.

    Attributes
    ----------
    letter
        Upper-cased letter, e.g. ``"X"``.
    value
        The number, or ``None`` for a valueless word or a quoted string.
    text
        The word exactly as written (``x.5``, ``P"MK3S"``).
    malformed
        True if the letter is followed by something that is not a number.
    """

    letter: str
    value: float | None
    text: bytes
    malformed: bool = False


@dataclass(frozen=True)
class ParsedLine:
    """A line split into segments; see :func:`parse_line`."""

    segments: tuple[Segment, ...]
    kind: str  # blank | comment | command | extended | words | other
    letter: str | None
    major: int | None
    minor: int | None
    line_number: int | None
    checksum: int | None
    checksum_ok: bool
    words: tuple[Word, ...]
    comment: bytes | None
    bad_column: int | None
    control_column: int | None

    def to_bytes(self) -> bytes:
        """The line, byte for byte as it was read."""
        return b"".join(s.text for s in self.segments)

    @property
    def command(self) -> str | None:
        """``"G1"``, ``"M862.3"``, ``"EXCLUDE_OBJECT_DEFINE"`` (upper-cased) or None."""
        for s in self.segments:
            if s.kind == "command":
                return s.text.decode("ascii").upper()
        return None

    def word(self, letter: str) -> Word | None:
        """The first word with this letter, or None."""
        for w in self.words:
            if w.letter == letter:
                return w
        return None


def _split_eol(raw: bytes) -> tuple[bytes, bytes]:
    if raw.endswith(b"\r\n"):
        return raw[:-2], b"\r\n"
    if raw.endswith((b"\n", b"\r")):
        return raw[:-1], raw[-1:]
    return raw, b""


def parse_line(raw: bytes) -> ParsedLine:
    """Split one raw line into a lossless token stream.

    Parameters
    ----------
    raw
        The line's bytes, with or without its terminator. A terminator may
        only appear at the end.

    Returns
    -------
    ParsedLine
        ``result.to_bytes() == raw`` always holds.
    """
    content, eol = _split_eol(raw)
    segs: list[Segment] = []
    words: list[Word] = []
    m = _CONTROL.search(content)
    control_column = m.start() if m else None
    semi = content.find(b";")
    body = content if semi < 0 else content[:semi]
    comment = None if semi < 0 else content[semi:]
    stripped = body.rstrip(b" \t")
    trailing = body[len(stripped) :]
    body = stripped

    kind = "blank"
    letter = None
    major = minor = None
    line_number = None
    checksum = None
    checksum_ok = False
    bad_column = None

    def ws_at(pos: int) -> int:
        m = _BLANKS.match(body, pos)
        if m.end() > pos:
            segs.append(Segment("ws", body[pos : m.end()]))
        return m.end()

    i = 0
    if body.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte-order mark
        segs.append(Segment("bom", body[:3]))
        i = 3
    i = ws_at(i)
    m = _NWORD.match(body, i)
    if m:
        line_number = int(m.group(1))
        segs.append(Segment("number", m.group(0)))
        i = ws_at(m.end())
    parse_words = True
    if i >= len(body):
        kind = "words" if line_number is not None else ("comment" if comment else "blank")
        parse_words = False
    elif body[i : i + 1] == b"*":
        kind = "words"
    elif body[i : i + 1].isalpha() and body[i] < 128:
        mc = _CMD.match(body, i)
        mi = _IDENT.match(body, i)
        if mc:
            kind = "command"
            letter = mc.group(1).decode().upper()
            major = int(mc.group(2))
            minor = int(mc.group(3)) if mc.group(3) is not None else None
            segs.append(Segment("command", mc.group(0)))
            i = mc.end()
            if letter == "M" and major in STRING_ARG_MCODES:
                parse_words = False
        elif mi:
            kind = "extended"
            letter = body[i : i + 1].decode().upper()
            segs.append(Segment("command", mi.group(0)))
            i = mi.end()
            parse_words = False
        else:
            kind = "words"
    else:
        kind = "other"
        bad_column = i
        parse_words = False

    if not parse_words:
        if i < len(body):
            if kind == "other":
                segs.append(Segment("bad", body[i:]))
            else:
                i = ws_at(i)
                if i < len(body):
                    segs.append(Segment("text", body[i:]))
        i = len(body)

    while i < len(body):
        i = ws_at(i)
        if i >= len(body):
            break
        ch = body[i : i + 1]
        if ch == b"*":
            mk = _CHECKSUM.match(body, i)
            if mk:
                checksum = int(mk.group(1))
                x = 0
                for b in body[:i]:
                    x ^= b
                checksum_ok = x == checksum
                segs.append(Segment("checksum", mk.group(0)))
            else:
                if bad_column is None:
                    bad_column = i
                segs.append(Segment("bad", body[i:]))
            break
        if ch == b'"':
            mq = _QUOTED.match(body, i)
            segs.append(Segment("string", mq.group(0)))
            words.append(Word("", None, mq.group(0)))
            i = mq.end()
            continue
        if not (ch.isalpha() and body[i] < 128):
            if bad_column is None:
                bad_column = i
            mb = _NONBLANK.match(body, i)
            segs.append(Segment("bad", mb.group(0)))
            words.append(Word("", None, mb.group(0), malformed=True))
            i = mb.end()
            continue
        L = ch.decode().upper()
        if body[i + 1 : i + 2] == b'"':
            mq = _QUOTED.match(body, i + 1)
            text = body[i : mq.end()]
            segs.append(Segment("word", text))
            words.append(Word(L, None, text))
            i = mq.end()
            continue
        mn = _NUMWORD.match(body, i)
        j = mn.end()
        nxt = body[j : j + 1]
        ok_end = nxt in (b"", b" ", b"\t", b"*") or (nxt.isalpha() and body[j] < 128)
        ndig = len(mn.group(2)) + len(mn.group(4) or b"")
        if j == i + 1 and ok_end:
            words.append(Word(L, None, body[i:j]))
        elif ndig == 0 or not ok_end:
            if not ok_end:
                j = _NONBLANK.match(body, j).end()
            if bad_column is None:
                bad_column = i
            words.append(Word(L, None, body[i:j], malformed=True))
        else:
            words.append(Word(L, float(body[i + 1 : j]), body[i:j]))
        segs.append(Segment("word", body[i:j]))
        i = j

    if trailing:
        segs.append(Segment("ws", trailing))
    if comment is not None:
        segs.append(Segment("comment", comment))
    if eol:
        segs.append(Segment("eol", eol))
    return ParsedLine(
        segments=tuple(segs),
        kind=kind,
        letter=letter,
        major=major,
        minor=minor,
        line_number=line_number,
        checksum=checksum,
        checksum_ok=checksum_ok,
        words=tuple(words),
        comment=comment,
        bad_column=bad_column,
        control_column=control_column,
    )


_PARAM = re.compile(rb"([A-Za-z_][A-Za-z0-9_]*)=")


def extended_params(raw: bytes) -> dict[str, str]:
    """``KEY=VALUE`` parameters of a named (Klipper-style) command.

    Values run to the next blank outside brackets and quotes, so
    ``POLYGON=[[1,2], [3,4]]`` and ``MSG="a b"`` stay whole. Keys are
    upper-cased; values are returned as written (decoded as UTF-8 with
    replacement). The command name itself is not included.

    >>> extended_params(b"EXCLUDE_OBJECT_DEFINE NAME=a CENTER=1,2 POLYGON=[[0,0],[1,0]]\\n")
    {'NAME': 'a', 'CENTER': '1,2', 'POLYGON': '[[0,0],[1,0]]'}
    """
    content, _ = _split_eol(raw)
    semi = content.find(b";")
    body = content if semi < 0 else content[:semi]
    m = _IDENT.match(body.lstrip(b" \t"))
    i = (len(body) - len(body.lstrip(b" \t"))) + (m.end() if m else 0)
    out: dict[str, str] = {}
    n = len(body)
    while i < n:
        while i < n and body[i] in b" \t":
            i += 1
        mk = _PARAM.match(body, i)
        if not mk:
            j = _NONBLANK.match(body, i).end()  # a bare token: skip it
            i = max(j, i + 1)
            continue
        j = mk.end()
        depth = 0
        quote = False
        while j < n:
            c = body[j]
            if c == 0x22:
                quote = not quote
            elif not quote and c in b"[(":
                depth += 1
            elif not quote and c in b"])":
                depth -= 1
            elif not quote and depth <= 0 and c in b" \t":
                break
            j += 1
        out[mk.group(1).decode("ascii").upper()] = body[mk.end() : j].decode("utf-8", "replace")
        i = j
    return out
