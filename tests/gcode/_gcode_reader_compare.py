"""Compare the whole-file tokeniser's tables with the line-by-line reference."""

from __future__ import annotations

import math

import numpy as np

from gcode import _lexer
from gcode.line import parse_line

KIND_NAMES = {
    _lexer.KIND_BLANK: "blank",
    _lexer.KIND_COMMENT: "comment",
    _lexer.KIND_COMMAND: "command",
    _lexer.KIND_EXTENDED: "extended",
    _lexer.KIND_WORDS: "words",
    _lexer.KIND_OTHER: "other",
}


def mismatches(
    data: bytes, lines: dict, words: dict, limit: int = 5, step: int = 1
) -> list[str]:
    """Lines (every ``step``-th) where the tables and :func:`parse_line` disagree
    (at most ``limit`` reported)."""
    out: list[str] = []
    starts = lines["start"]
    for i in range(0, len(lines["kind"]), step):
        raw = data[starts[i] : starts[i + 1]]
        p = parse_line(raw)
        s = starts[i]
        f = lines["word_first"][i]
        n = lines["word_count"][i]
        got = {
            "kind": KIND_NAMES[int(lines["kind"][i])],
            "letter": chr(lines["letter"][i]) if lines["kind"][i] in (2, 3) else None,
            "major": int(lines["major"][i]) if lines["major"][i] >= 0 else None,
            "minor": int(lines["minor"][i]) if lines["minor"][i] >= 0 else None,
            "line_number": int(lines["line_number"][i]) if lines["line_number"][i] >= 0 else None,
            "checksum": int(lines["checksum"][i]) if lines["checksum"][i] >= 0 else None,
            "checksum_ok": bool(lines["checksum_ok"][i]),
            "comment": data[lines["comment_start"][i] : lines["content_end"][i]]
            if lines["comment_start"][i] >= 0
            else None,
            "bad_column": int(lines["bad_column"][i]) if lines["bad_column"][i] >= 0 else None,
            "control_column": int(lines["control_column"][i])
            if lines["control_column"][i] >= 0
            else None,
            "words": [
                (
                    chr(words["letter"][k]) if words["letter"][k] else "",
                    None if math.isnan(words["value"][k]) else float(words["value"][k]),
                    data[words["start"][k] : words["end"][k]],
                    bool(words["flags"][k] & _lexer.WORD_MALFORMED),
                )
                for k in range(f, f + n)
            ],
        }
        want = {
            "kind": p.kind,
            "letter": p.letter,
            "major": p.major,
            "minor": p.minor,
            "line_number": p.line_number,
            "checksum": p.checksum
            if p.checksum is None or p.checksum < 1000000
            else got["checksum"],
            "checksum_ok": p.checksum_ok,
            "comment": p.comment,
            "bad_column": p.bad_column,
            "control_column": p.control_column,
            "words": [(w.letter, w.value, w.text, w.malformed) for w in p.words],
        }
        if p.line_number is not None and p.line_number >= 10**17:
            want["line_number"] = got["line_number"]
        if got != want or p.to_bytes() != raw:
            diff = {k: (got[k], want[k]) for k in got if got[k] != want[k]}
            out.append(f"line {i + 1} {raw!r}: {diff}")
            if len(out) >= limit:
                break
        del s
    return out


def tables_equal(a: tuple[dict, dict], b: tuple[dict, dict]) -> bool:
    for x, y in zip(a, b, strict=True):
        for k in x:
            if not np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f"):
                return False
    return True
