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


def _lex_impl(buf, string_codes, pow10):
    n = len(buf)
    # Count lines: a line ends at \n, or at a \r not followed by \n.
    # First pass: count lines, and bound the number of words from above by
    # counting, outside comments, the bytes that can start a word (a letter,
    # a quote, or any byte after a blank). Sizing the tables once keeps the
    # second pass free of reallocation.
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

    start = np.empty(nlines + 1, np.int64)
    cend = np.empty(nlines, np.int64)
    cstart = np.full(nlines, -1, np.int64)
    kind = np.zeros(nlines, np.uint8)
    letter = np.zeros(nlines, np.uint8)
    major = np.full(nlines, -1, np.int32)
    minor = np.full(nlines, -1, np.int32)
    cmd_end = np.zeros(nlines, np.int64)
    nnum = np.full(nlines, -1, np.int64)
    cksum = np.full(nlines, -1, np.int32)
    cksum_ok = np.zeros(nlines, np.bool_)
    wfirst = np.zeros(nlines, np.int64)
    wcount = np.zeros(nlines, np.int32)
    bad = np.full(nlines, -1, np.int32)
    ctrl = np.full(nlines, -1, np.int32)

    cap += 1
    w_line = np.empty(cap, np.int32)
    w_letter = np.empty(cap, np.uint8)
    w_value = np.empty(cap, np.float64)
    w_start = np.empty(cap, np.int64)
    w_end = np.empty(cap, np.int64)
    w_flags = np.empty(cap, np.uint8)
    nw = 0

    p = 0
    li = 0
    while li < nlines:
        s = p
        # find the end of the content and the start of the next line
        e = s
        while e < n and buf[e] != 10 and buf[e] != 13:
            e += 1
        if e < n:
            if buf[e] == 13 and e + 1 < n and buf[e + 1] == 10:
                nxt = e + 2
            else:
                nxt = e + 1
        else:
            nxt = n
        start[li] = s
        cend[li] = e
        p = nxt
        wfirst[li] = nw

        # control bytes and the comment start
        bend = e
        for q in range(s, e):
            c = buf[q]
            if (c < 32 and c != 9) or c == 127:
                if ctrl[li] < 0:
                    ctrl[li] = q - s
            if c == 59 and bend == e:  # ';'
                bend = q
        if bend < e:
            cstart[li] = bend
        # trailing whitespace of the body is not part of any token
        while bend > s and (buf[bend - 1] == 32 or buf[bend - 1] == 9):
            bend -= 1

        i = s
        # a UTF-8 byte-order mark (some editors write one) is not content
        if i + 2 < bend and buf[i] == 0xEF and buf[i + 1] == 0xBB and buf[i + 2] == 0xBF:
            i += 3
        while i < bend and (buf[i] == 32 or buf[i] == 9):
            i += 1
        # optional N line number
        if i + 1 < bend and (buf[i] | 32) == 110 and 48 <= buf[i + 1] <= 57:
            j = i + 1
            v = 0
            while j < bend and 48 <= buf[j] <= 57:
                if v < 100000000000000000:
                    v = v * 10 + (buf[j] - 48)
                j += 1
            if j >= bend or buf[j] == 32 or buf[j] == 9 or buf[j] == 42:
                nnum[li] = v
                i = j
                while i < bend and (buf[i] == 32 or buf[i] == 9):
                    i += 1
        if i >= bend:
            if nnum[li] >= 0:
                kind[li] = KIND_WORDS
            elif cstart[li] >= 0:
                kind[li] = KIND_COMMENT
            else:
                kind[li] = KIND_BLANK
            li += 1
            continue

        c = buf[i]
        cu = c & 223  # upper-case for ASCII letters
        is_letter = 65 <= cu <= 90 and c < 128
        parse_words = True
        if c == 42:
            kind[li] = KIND_WORDS
        elif is_letter:
            c1 = buf[i + 1] if i + 1 < bend else 32
            c1u = c1 & 223
            if (cu == 71 or cu == 77 or cu == 84) and 48 <= c1 <= 57:  # G M T + digit
                kind[li] = KIND_COMMAND
                letter[li] = cu
                j = i + 1
                v = 0
                while j < bend and 48 <= buf[j] <= 57:
                    if v < 100000000:
                        v = v * 10 + (buf[j] - 48)
                    j += 1
                major[li] = v
                if j + 1 < bend and buf[j] == 46 and 48 <= buf[j + 1] <= 57:
                    j += 1
                    v = 0
                    while j < bend and 48 <= buf[j] <= 57:
                        if v < 100000000:
                            v = v * 10 + (buf[j] - 48)
                        j += 1
                    minor[li] = v
                cmd_end[li] = j
                i = j
                if cu == 77:
                    for k in range(string_codes.shape[0]):
                        if string_codes[k] == major[li]:
                            parse_words = False
            elif (65 <= c1u <= 90 and c1 < 128) or c1 == 95:  # identifier: macro
                kind[li] = KIND_EXTENDED
                letter[li] = cu
                j = i + 1
                while j < bend:
                    cj = buf[j]
                    cju = cj & 223
                    if (65 <= cju <= 90 and cj < 128) or 48 <= cj <= 57 or cj == 95:
                        j += 1
                    else:
                        break
                cmd_end[li] = j
                parse_words = False
            else:
                kind[li] = KIND_WORDS
        else:
            kind[li] = KIND_OTHER
            bad[li] = i - s
            parse_words = False

        if parse_words:
            while i < bend:
                while i < bend and (buf[i] == 32 or buf[i] == 9):
                    i += 1
                if i >= bend:
                    break
                c = buf[i]
                if c == 42:  # '*' checksum: digits, then only the end of the body
                    j = i + 1
                    v = 0
                    while j < bend and 48 <= buf[j] <= 57:
                        if v < 1000000:
                            v = v * 10 + (buf[j] - 48)
                        j += 1
                    if j == bend and j > i + 1:
                        cksum[li] = v
                        x = 0
                        for q in range(s, i):
                            x ^= buf[q]
                        cksum_ok[li] = x == v
                    elif bad[li] < 0:
                        bad[li] = i - s
                    break
                cu = c & 223
                if c == 34:  # a bare "quoted string" (M862.3 P "MK3S")
                    j = i + 1
                    while j < bend:
                        if buf[j] == 34:
                            if j + 1 < bend and buf[j + 1] == 34:
                                j += 2
                                continue
                            j += 1
                            break
                        j += 1
                    w_line[nw] = li
                    w_letter[nw] = 0
                    w_value[nw] = np.nan
                    w_start[nw] = i
                    w_end[nw] = j
                    w_flags[nw] = WORD_QUOTED
                    nw += 1
                    i = j
                    continue
                if not (65 <= cu <= 90 and c < 128):
                    # not a word: swallow up to the next blank and flag the line
                    if bad[li] < 0:
                        bad[li] = i - s
                    j = i
                    while j < bend and buf[j] != 32 and buf[j] != 9:
                        j += 1
                    w_line[nw] = li
                    w_letter[nw] = 0
                    w_value[nw] = np.nan
                    w_start[nw] = i
                    w_end[nw] = j
                    w_flags[nw] = WORD_MALFORMED
                    nw += 1
                    i = j
                    continue
                j = i + 1
                flags = 0
                value = np.nan
                if j < bend and buf[j] == 34:  # quoted string, "" escapes a quote
                    j += 1
                    while j < bend:
                        if buf[j] == 34:
                            if j + 1 < bend and buf[j + 1] == 34:
                                j += 2
                                continue
                            j += 1
                            break
                        j += 1
                    flags = WORD_QUOTED
                else:
                    neg = False
                    if j < bend and (buf[j] == 45 or buf[j] == 43):
                        neg = buf[j] == 45
                        j += 1
                    mant = 0
                    ndig = 0
                    nfrac = 0
                    seen_dot = False
                    while j < bend:
                        cj = buf[j]
                        if 48 <= cj <= 57:
                            if ndig < 15:
                                mant = mant * 10 + (cj - 48)
                                if seen_dot:
                                    nfrac += 1
                            else:
                                flags |= WORD_INEXACT
                            ndig += 1
                            j += 1
                        elif cj == 46 and not seen_dot:
                            seen_dot = True
                            j += 1
                        else:
                            break
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
                    else:
                        if nfrac <= 22:
                            value = mant / pow10[nfrac]
                        else:
                            flags |= WORD_INEXACT
                            value = 0.0
                        if neg:
                            value = -value
                    if not ok_end:
                        while j < bend and buf[j] != 32 and buf[j] != 9:
                            j += 1
                    if flags & WORD_MALFORMED and bad[li] < 0:
                        bad[li] = i - s
                w_line[nw] = li
                w_letter[nw] = cu
                w_value[nw] = value
                w_start[nw] = i
                w_end[nw] = j
                w_flags[nw] = flags
                nw += 1
                i = j
        wcount[li] = nw - wfirst[li]
        li += 1
    start[nlines] = n
    return (
        start, cend, cstart, kind, letter, major, minor, cmd_end, nnum, cksum, cksum_ok,
        wfirst, wcount, bad, ctrl,
        w_line[:nw].copy(), w_letter[:nw].copy(), w_value[:nw].copy(),
        w_start[:nw].copy(), w_end[:nw].copy(), w_flags[:nw].copy(),
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


LINE_FIELDS = (
    "start", "content_end", "comment_start", "kind", "letter", "major", "minor", "command_end",
    "line_number", "checksum", "checksum_ok", "word_first", "word_count", "bad_column",
    "control_column",
)
WORD_FIELDS = ("line", "letter", "value", "start", "end", "flags")


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
    out = _kernel(engine)(buf, np.array(STRING_ARG_MCODES, np.int64), _POW10)
    nl = len(LINE_FIELDS)
    lines = dict(zip(LINE_FIELDS, out[:nl], strict=True))
    words = dict(zip(WORD_FIELDS, out[nl:], strict=True))
    inexact = np.flatnonzero(words["flags"] & WORD_INEXACT)
    for k in inexact:  # very long numbers: let Python convert them exactly
        text = data[words["start"][k] + 1 : words["end"][k]]
        words["value"][k] = float(text)
        words["flags"][k] &= 0xFF ^ WORD_INEXACT
    return lines, words
