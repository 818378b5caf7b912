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


class _Scan:
    """The state of :func:`parse_line` on one line's body: the segments and words so far and
    the line's fields."""

    def __init__(self, body: bytes) -> None:
        self.body = body
        self.segs: list[Segment] = []
        self.words: list[Word] = []
        self.kind = "blank"
        self.letter: str | None = None
        self.major: int | None = None
        self.minor: int | None = None
        self.line_number: int | None = None
        self.checksum: int | None = None
        self.checksum_ok = False
        self.bad_column: int | None = None

    def blanks(self, pos: int) -> int:
        """Past the blanks at ``pos`` (a ``ws`` segment if any)."""
        m = _BLANKS.match(self.body, pos)
        if m.end() > pos:
            self.segs.append(Segment("ws", self.body[pos : m.end()]))
        return m.end()

    def bad(self, pos: int) -> None:
        if self.bad_column is None:
            self.bad_column = pos

    def head(self, has_comment: bool) -> tuple[int, bool]:
        """Byte-order mark, ``N`` number and command: (where the words start, whether the
        line has address words to read)."""
        body = self.body
        i = 0
        if body.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte-order mark
            self.segs.append(Segment("bom", body[:3]))
            i = 3
        i = self.blanks(i)
        m = _NWORD.match(body, i)
        if m:
            self.line_number = int(m.group(1))
            self.segs.append(Segment("number", m.group(0)))
            i = self.blanks(m.end())
        if i >= len(body):
            self.kind = "words" if self.line_number is not None else (
                "comment" if has_comment else "blank")
            return i, False
        if body[i : i + 1] == b"*":
            self.kind = "words"
            return i, True
        if not (body[i : i + 1].isalpha() and body[i] < 128):
            self.kind = "other"
            self.bad_column = i
            return i, False
        mc = _CMD.match(body, i)
        if mc:
            self.kind = "command"
            self.letter = mc.group(1).decode().upper()
            self.major = int(mc.group(2))
            self.minor = int(mc.group(3)) if mc.group(3) is not None else None
            self.segs.append(Segment("command", mc.group(0)))
            return mc.end(), not (self.letter == "M" and self.major in STRING_ARG_MCODES)
        mi = _IDENT.match(body, i)
        if mi:
            self.kind = "extended"
            self.letter = body[i : i + 1].decode().upper()
            self.segs.append(Segment("command", mi.group(0)))
            return mi.end(), False
        self.kind = "words"
        return i, True

    def rest(self, i: int) -> None:
        """The rest of the body as one segment: ``bad`` on an "other" line, else free text."""
        body = self.body
        if i < len(body):
            if self.kind == "other":
                self.segs.append(Segment("bad", body[i:]))
            else:
                i = self.blanks(i)
                if i < len(body):
                    self.segs.append(Segment("text", body[i:]))

    def address_words(self, i: int) -> None:
        """The words from ``i`` to the end of the body (or its ``*`` checksum)."""
        body = self.body
        while i < len(body):
            i = self.blanks(i)
            if i >= len(body):
                break
            ch = body[i : i + 1]
            if ch == b"*":
                self.checksum_at(i)
                break
            if ch == b'"':
                mq = _QUOTED.match(body, i)
                self.segs.append(Segment("string", mq.group(0)))
                self.words.append(Word("", None, mq.group(0)))
                i = mq.end()
            elif not (ch.isalpha() and body[i] < 128):
                self.bad(i)
                mb = _NONBLANK.match(body, i)
                self.segs.append(Segment("bad", mb.group(0)))
                self.words.append(Word("", None, mb.group(0), malformed=True))
                i = mb.end()
            else:
                i = self.word(i, ch.decode().upper())

    def checksum_at(self, i: int) -> None:
        body = self.body
        mk = _CHECKSUM.match(body, i)
        if mk:
            self.checksum = int(mk.group(1))
            x = 0
            for b in body[:i]:
                x ^= b
            self.checksum_ok = x == self.checksum
            self.segs.append(Segment("checksum", mk.group(0)))
        else:
            self.bad(i)
            self.segs.append(Segment("bad", body[i:]))

    def word(self, i: int, letter: str) -> int:
        """The word of ``letter`` at ``i``: a quoted string, a number, nothing or something
        malformed; where it ends."""
        body = self.body
        if body[i + 1 : i + 2] == b'"':
            mq = _QUOTED.match(body, i + 1)
            text = body[i : mq.end()]
            self.segs.append(Segment("word", text))
            self.words.append(Word(letter, None, text))
            return mq.end()
        mn = _NUMWORD.match(body, i)
        j = mn.end()
        nxt = body[j : j + 1]
        ok_end = nxt in (b"", b" ", b"\t", b"*") or (nxt.isalpha() and body[j] < 128)
        ndig = len(mn.group(2)) + len(mn.group(4) or b"")
        if j == i + 1 and ok_end:
            self.words.append(Word(letter, None, body[i:j]))
        elif ndig == 0 or not ok_end:
            if not ok_end:
                j = _NONBLANK.match(body, j).end()
            self.bad(i)
            self.words.append(Word(letter, None, body[i:j], malformed=True))
        else:
            self.words.append(Word(letter, float(body[i + 1 : j]), body[i:j]))
        self.segs.append(Segment("word", body[i:j]))
        return j


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
    m = _CONTROL.search(content)
    semi = content.find(b";")
    body = content if semi < 0 else content[:semi]
    comment = None if semi < 0 else content[semi:]
    stripped = body.rstrip(b" \t")
    trailing = body[len(stripped) :]
    scan = _Scan(stripped)
    i, parse_words = scan.head(bool(comment))
    if parse_words:
        scan.address_words(i)
    else:
        scan.rest(i)
    segs = scan.segs
    if trailing:
        segs.append(Segment("ws", trailing))
    if comment is not None:
        segs.append(Segment("comment", comment))
    if eol:
        segs.append(Segment("eol", eol))
    return ParsedLine(
        segments=tuple(segs),
        kind=scan.kind,
        letter=scan.letter,
        major=scan.major,
        minor=scan.minor,
        line_number=scan.line_number,
        checksum=scan.checksum,
        checksum_ok=scan.checksum_ok,
        words=tuple(scan.words),
        comment=comment,
        bad_column=scan.bad_column,
        control_column=m.start() if m else None,
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
