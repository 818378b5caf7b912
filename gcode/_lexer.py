"""Whole-file tokeniser: one pass over the bytes, numpy tables out.

The kernel walks the raw bytes once and fills two tables:

* a *line* table (one row per physical line): where the line starts, where
  its content ends (before ``\\n`` / ``\\r\\n`` / a lone ``\\r``), where its
  ``;`` comment starts, what kind of line it is, its command letter and
  number (``M862.3`` → ``M``, 862, 3), its ``N`` line number and ``*``
  checksum, and which rows of the word table belong to it;
* a *word* table (one row per address word ``X12.5``): the line it is on,
  its letter (upper-cased), its value (NaN for a valueless word such as the
  ``X`` of ``M84 X Y E`` or a quoted string) and its byte span.

Nothing is copied out of the buffer and nothing is normalised, so a line is
always ``data[start[i]:start[i+1]]``, byte for byte. The kernel is compiled
with numba when it is importable (``engine="numba"``) and is plain Python
otherwise; :func:`gcode.line.parse_line` is an independent pure-Python
tokeniser of single lines that the tests hold the tables against.

Complexity: O(bytes) time, O(lines + words) memory.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = [
    "KIND_BLANK",
    "KIND_COMMAND",
    "KIND_COMMENT",
    "KIND_EXTENDED",
    "KIND_OTHER",
    "KIND_WORDS",
    "STRING_ARG_MCODES",
    "WORD_INEXACT",
    "WORD_MALFORMED",
    "WORD_QUOTED",
    "WORD_VALUELESS",
    "lex",
]

# Line kinds.
KIND_BLANK = 0  # nothing but whitespace
KIND_COMMENT = 1  # only a ; comment (and whitespace)
KIND_COMMAND = 2  # G/M/T command with a number: G1, M862.3, T0
KIND_EXTENDED = 3  # Klipper-style named command: EXCLUDE_OBJECT_DEFINE NAME=...
KIND_WORDS = 4  # address words without a command letter: "X10 Y20"
KIND_OTHER = 5  # anything else (starts with a digit or punctuation)

# Word flags.
WORD_VALUELESS = 1  # letter alone: the X of "M84 X Y E"
WORD_QUOTED = 2  # letter followed by a "quoted string"
WORD_MALFORMED = 4  # letter followed by something that is not a number
WORD_INEXACT = 8  # more digits than the kernel converts exactly; redo in Python

# M-codes whose argument is free text (Marlin / RepRapFirmware): M23 file,
# M28/M29/M30/M32/M33 file names, M117/M118 messages, M928 log file.
STRING_ARG_MCODES = (23, 28, 29, 30, 32, 33, 117, 118, 928)

_POW10 = np.array([10.0**k for k in range(23)])


try:
    from numba.extending import register_jitable
except ImportError:  # pragma: no cover - numba is a declared dependency

    def register_jitable(fn=None, **_options):
        return fn if fn is not None else (lambda f: f)

# The helpers run interpreted as they are (engine "python") and are compiled into the kernel
# when :func:`_lex_impl` is. They allocate nothing: no reference counting, which (a count per
# array per call, several calls per word) would also keep LLVM from inlining them.
_jitable = register_jitable(_nrt=False)


class _LineTable(NamedTuple):
    """One row per physical line (see :data:`LINE_FIELDS`); ``start`` has one more."""

    start: np.ndarray
    content_end: np.ndarray
    comment_start: np.ndarray
    kind: np.ndarray
    letter: np.ndarray
    major: np.ndarray
    minor: np.ndarray
    command_end: np.ndarray
    line_number: np.ndarray
    checksum: np.ndarray
    checksum_ok: np.ndarray
    word_first: np.ndarray
    word_count: np.ndarray
    bad_column: np.ndarray
    control_column: np.ndarray


class _WordTable(NamedTuple):
    """One row per address word (see :data:`WORD_FIELDS`)."""

    line: np.ndarray
    letter: np.ndarray
    value: np.ndarray
    start: np.ndarray
    end: np.ndarray
    flags: np.ndarray


@_jitable
def _count_lines(buf):
    """(lines, an upper bound on the words): the first pass, which sizes the tables once so
    that the second is free of reallocation. A line ends at \\n, or at a \\r not followed by
    \\n; a word can start, outside comments, at a letter, a quote or any byte after a blank."""
    n = len(buf)
    nlines = 0
    cap = 0
    in_comment = False
    prev_blank = True
    for p in range(n):
        c = buf[p]
        if c == 10 or c == 13:
            if c == 10 or p + 1 >= n or buf[p + 1] != 10:
                nlines += 1
            in_comment = False
            prev_blank = True
        elif not in_comment:
            if c == 59:
                in_comment = True
            elif c == 32 or c == 9:
                prev_blank = True
            else:
                if prev_blank or c == 34 or 65 <= (c & 223) <= 90:
                    cap += 1
                prev_blank = False
    if n > 0 and not (buf[n - 1] == 10 or buf[n - 1] == 13):
        nlines += 1
    return nlines, cap + 1


@register_jitable
def _new_tables(nlines, cap):
    lines = _LineTable(
        np.empty(nlines + 1, np.int64),  # start
        np.empty(nlines, np.int64),  # content_end
        np.full(nlines, -1, np.int64),  # comment_start
        np.zeros(nlines, np.uint8),  # kind
        np.zeros(nlines, np.uint8),  # letter
        np.full(nlines, -1, np.int32),  # major
        np.full(nlines, -1, np.int32),  # minor
        np.zeros(nlines, np.int64),  # command_end
        np.full(nlines, -1, np.int64),  # line_number
        np.full(nlines, -1, np.int32),  # checksum
        np.zeros(nlines, np.bool_),  # checksum_ok
        np.zeros(nlines, np.int64),  # word_first
        np.zeros(nlines, np.int32),  # word_count
        np.full(nlines, -1, np.int32),  # bad_column
        np.full(nlines, -1, np.int32),  # control_column
    )
    words = _WordTable(
        np.empty(cap, np.int32), np.empty(cap, np.uint8), np.empty(cap, np.float64),
        np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.uint8),
    )
    return lines, words


@_jitable
def _line_end(buf, s, n):
    """(end of the content, start of the next line) of the line starting at ``s``."""
    e = s
    while e < n and buf[e] != 10 and buf[e] != 13:
        e += 1
    if e < n:
        if buf[e] == 13 and e + 1 < n and buf[e + 1] == 10:
            return e, e + 2
        return e, e + 1
    return e, n


@_jitable
def _body_end(buf, s, e, li, lines):
    """The end of the line's body (before its comment and trailing blanks); records the
    first control byte and the comment's start."""
    bend = e
    for q in range(s, e):
        c = buf[q]
        if (c < 32 and c != 9) or c == 127:
            if lines.control_column[li] < 0:
                lines.control_column[li] = q - s
        if c == 59 and bend == e:  # ';'
            bend = q
    if bend < e:
        lines.comment_start[li] = bend
    # trailing whitespace of the body is not part of any token
    while bend > s and (buf[bend - 1] == 32 or buf[bend - 1] == 9):
        bend -= 1
    return bend


@_jitable
def _skip_blanks(buf, i, bend):
    while i < bend and (buf[i] == 32 or buf[i] == 9):
        i += 1
    return i


@_jitable
def _digits(buf, j, bend, limit):
    """(end, value) of the decimal digits at ``j``; the value stops growing at ``limit``."""
    v = 0
    while j < bend and 48 <= buf[j] <= 57:
        if v < limit:
            v = v * 10 + (buf[j] - 48)
        j += 1
    return j, v


@_jitable
def _line_start(buf, s, bend, li, lines):
    """Past a byte-order mark, blanks and an ``N`` line number: where the command starts."""
    i = s
    # a UTF-8 byte-order mark (some editors write one) is not content
    if i + 2 < bend and buf[i] == 0xEF and buf[i + 1] == 0xBB and buf[i + 2] == 0xBF:
        i += 3
    i = _skip_blanks(buf, i, bend)
    if i + 1 < bend and (buf[i] | 32) == 110 and 48 <= buf[i + 1] <= 57:  # N + digit
        j, v = _digits(buf, i + 1, bend, 100000000000000000)
        if j >= bend or buf[j] == 32 or buf[j] == 9 or buf[j] == 42:
            lines.line_number[li] = v
            i = _skip_blanks(buf, j, bend)
    return i


@_jitable
def _command(buf, s, i, bend, li, lines, string_codes):
    """Classify the line from its first token at ``i`` (its kind, command letter and
    number); (where its words start, whether it has address words to read)."""
    c = buf[i]
    cu = c & 223  # upper-case for ASCII letters
    if c == 42:
        lines.kind[li] = KIND_WORDS
        return i, True
    if not (65 <= cu <= 90 and c < 128):
        lines.kind[li] = KIND_OTHER
        lines.bad_column[li] = i - s
        return i, False
    c1 = buf[i + 1] if i + 1 < bend else 32
    c1u = c1 & 223
    if (cu == 71 or cu == 77 or cu == 84) and 48 <= c1 <= 57:  # G M T + digit
        lines.kind[li] = KIND_COMMAND
        lines.letter[li] = cu
        j, v = _digits(buf, i + 1, bend, 100000000)
        lines.major[li] = v
        if j + 1 < bend and buf[j] == 46 and 48 <= buf[j + 1] <= 57:
            j, v = _digits(buf, j + 1, bend, 100000000)
            lines.minor[li] = v
        lines.command_end[li] = j
        if cu == 77:
            for k in range(string_codes.shape[0]):
                if string_codes[k] == lines.major[li]:
                    return j, False
        return j, True
    if (65 <= c1u <= 90 and c1 < 128) or c1 == 95:  # identifier: macro
        lines.kind[li] = KIND_EXTENDED
        lines.letter[li] = cu
        j = i + 1
        while j < bend:
            cj = buf[j]
            cju = cj & 223
            if (65 <= cju <= 90 and cj < 128) or 48 <= cj <= 57 or cj == 95:
                j += 1
            else:
                break
        lines.command_end[li] = j
        return i, False
    lines.kind[li] = KIND_WORDS
    return i, True


@_jitable
def _quoted_end(buf, j, bend):
    """The end of a quoted string whose text starts at ``j`` ("" escapes a quote)."""
    while j < bend:
        if buf[j] == 34:
            if j + 1 < bend and buf[j + 1] == 34:
                j += 2
                continue
            return j + 1
        j += 1
    return j


@_jitable
def _put_word(words, nw, li, letter, value, i, j, flags):
    words.line[nw] = li
    words.letter[nw] = letter
    words.value[nw] = value
    words.start[nw] = i
    words.end[nw] = j
    words.flags[nw] = flags
    return nw + 1


@_jitable
def _checksum(buf, s, i, bend):
    """(value, whether it matches the line) of the ``*`` checksum at ``i``: digits, then only
    the end of the body; (-1, False) for anything else."""
    j, v = _digits(buf, i + 1, bend, 1000000)
    if j == bend and j > i + 1:
        x = 0
        for q in range(s, i):
            x ^= buf[q]
        return v, x == v
    return -1, False


@_jitable
def _mantissa(buf, j, bend):
    """(end, mantissa, digits, decimals, too many digits) of the digits and point at ``j``:
    the first 15 digits are exact in the mantissa."""
    mant = 0
    ndig = 0
    nfrac = 0
    inexact = False
    seen_dot = False
    while j < bend:
        cj = buf[j]
        if 48 <= cj <= 57:
            if ndig < 15:
                mant = mant * 10 + (cj - 48)
                if seen_dot:
                    nfrac += 1
            else:
                inexact = True
            ndig += 1
            j += 1
        elif cj == 46 and not seen_dot:
            seen_dot = True
            j += 1
        else:
            break
    return j, mant, ndig, nfrac, inexact


@_jitable
def _token_end(buf, j, bend):
    while j < bend and buf[j] != 32 and buf[j] != 9:
        j += 1
    return j


@_jitable
def _read_words(buf, lines, words, word_at, word_end, pow10):
    """The second pass: the address words of each line, from ``word_at`` (-1: none) to
    ``word_end``; the number of words. One function for all lines and words: a call per
    line or word would cost about as much as reading it."""
    nw = 0
    for li in range(word_at.shape[0]):
        lines.word_first[li] = nw
        i = word_at[li]
        if i < 0:
            continue
        bend = word_end[li]
        s = lines.start[li]
        bad = -1
        cks = -1
        cks_ok = False
        while i < bend:
            i = _skip_blanks(buf, i, bend)
            if i >= bend:
                break
            c = buf[i]
            if c == 42:  # '*' checksum
                cks, cks_ok = _checksum(buf, s, i, bend)
                if cks < 0 and bad < 0:
                    bad = i - s
                break
            cu = c & 223
            if c == 34:  # a bare "quoted string" (M862.3 P "MK3S")
                j = _quoted_end(buf, i + 1, bend)
                nw = _put_word(words, nw, li, 0, np.nan, i, j, WORD_QUOTED)
            elif not (65 <= cu <= 90 and c < 128):
                # not a word: swallow up to the next blank and flag the line
                if bad < 0:
                    bad = i - s
                j = _token_end(buf, i, bend)
                nw = _put_word(words, nw, li, 0, np.nan, i, j, WORD_MALFORMED)
            elif i + 1 < bend and buf[i + 1] == 34:  # letter + quoted string
                j = _quoted_end(buf, i + 2, bend)
                nw = _put_word(words, nw, li, cu, np.nan, i, j, WORD_QUOTED)
            else:  # letter + number
                j = i + 1
                neg = False
                if j < bend and (buf[j] == 45 or buf[j] == 43):
                    neg = buf[j] == 45
                    j += 1
                j, mant, ndig, nfrac, inexact = _mantissa(buf, j, bend)
                flags = WORD_INEXACT if inexact else 0
                value = np.nan
                # a number must be followed by a blank, the next word, '*' or the end
                ok_end = j >= bend
                if not ok_end:
                    cj = buf[j]
                    cju = cj & 223
                    ok_end = cj == 32 or cj == 9 or cj == 42 or (65 <= cju <= 90 and cj < 128)
                if j == i + 1 and ok_end:
                    flags = WORD_VALUELESS
                elif ndig == 0 or not ok_end:
                    flags = WORD_MALFORMED
                    if bad < 0:
                        bad = i - s
                    if not ok_end:
                        j = _token_end(buf, j, bend)
                else:
                    if nfrac <= 22:
                        value = mant / pow10[nfrac]
                    else:
                        flags |= WORD_INEXACT
                        value = 0.0
                    if neg:
                        value = -value
                nw = _put_word(words, nw, li, cu, value, i, j, flags)
            i = j
        lines.word_count[li] = nw - lines.word_first[li]
        if bad >= 0:
            lines.bad_column[li] = bad
        if cks >= 0:
            lines.checksum[li] = cks
            lines.checksum_ok[li] = cks_ok
    return nw


def _lex_impl(buf, string_codes, pow10):
    n = len(buf)
    nlines, cap = _count_lines(buf)
    lines, words = _new_tables(nlines, cap)
    word_at = np.full(nlines, -1, np.int64)  # where a line's address words start
    word_end = np.zeros(nlines, np.int64)
    p = 0
    for li in range(nlines):
        s = p
        e, p = _line_end(buf, s, n)
        lines.start[li] = s
        lines.content_end[li] = e
        bend = _body_end(buf, s, e, li, lines)
        i = _line_start(buf, s, bend, li, lines)
        if i >= bend:
            if lines.line_number[li] >= 0:
                lines.kind[li] = KIND_WORDS
            elif lines.comment_start[li] >= 0:
                lines.kind[li] = KIND_COMMENT
            else:
                lines.kind[li] = KIND_BLANK
            continue
        i, parse_words = _command(buf, s, i, bend, li, lines, string_codes)
        if parse_words:
            word_at[li] = i
            word_end[li] = bend
    lines.start[nlines] = n
    nw = _read_words(buf, lines, words, word_at, word_end, pow10)
    return lines, _WordTable(
        words.line[:nw].copy(), words.letter[:nw].copy(), words.value[:nw].copy(),
        words.start[:nw].copy(), words.end[:nw].copy(), words.flags[:nw].copy(),
    )


_compiled = None


def _kernel(engine: str):
    global _compiled
    if engine == "python":
        return _lex_impl
    if _compiled is None:
        try:
            import numba
        except ImportError:  # pragma: no cover - numba is a declared dependency
            _compiled = _lex_impl
        else:
            _compiled = numba.njit(cache=True, nogil=True)(_lex_impl)
    return _compiled


LINE_FIELDS = _LineTable._fields
WORD_FIELDS = _WordTable._fields


def lex(
    data: bytes, *, engine: str = "numba"
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Tokenise a whole G-code buffer.

    Parameters
    ----------
    data
        The file's bytes.
    engine
        ``"numba"`` (compiled; the default) or ``"python"`` (the same code
        interpreted: slow, for cross-checks and where numba is missing).

    Returns
    -------
    lines, words
        Dicts of equally long numpy arrays (see :data:`LINE_FIELDS`,
        :data:`WORD_FIELDS`). Byte offsets are absolute in ``data``;
        ``lines["start"]`` has one extra entry, ``len(data)``.
    """
    buf = bytes(data) if engine == "python" else np.frombuffer(data, dtype=np.uint8)
    line_table, word_table = _kernel(engine)(buf, np.array(STRING_ARG_MCODES, np.int64), _POW10)
    lines = dict(zip(LINE_FIELDS, line_table, strict=True))
    words = dict(zip(WORD_FIELDS, word_table, strict=True))
    inexact = np.flatnonzero(words["flags"] & WORD_INEXACT)
    for k in inexact:  # very long numbers: let Python convert them exactly
        text = data[words["start"][k] + 1 : words["end"][k]]
        words["value"][k] = float(text)
        words["flags"][k] &= 0xFF ^ WORD_INEXACT
    return lines, words
