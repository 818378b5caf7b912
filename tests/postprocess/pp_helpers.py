"""Helpers shared by the post-processing tests."""

from __future__ import annotations

import bisect
import re
from collections import defaultdict
from pathlib import Path

__all__ = ["first_layers", "geos_targets", "lines_not_kept"]

_C_WORD = re.compile(rb" C-?[0-9.]+")
_INSERTED = re.compile(rb"^(G92 E-?[0-9.]+|G1 C-?[0-9.]+|; printability.*)\r?\n?$")


def first_layers(path: Path, n: int, marker: bytes = b";LAYER_CHANGE") -> bytes:
    """The file up to (not including) its (n+1)-th layer marker: a valid, shorter G-code."""
    data = path.read_bytes()
    pos = -1
    for _ in range(n + 1):
        pos = data.find(b"\n" + marker, pos + 1)
        if pos < 0:
            return data
    return data[: pos + 1]


def lines_not_kept(old: bytes, new: bytes, may_change: set[int]) -> tuple[list[int], list[int]]:
    """Original lines (0-based) missing from the new file, in order, up to rotary words.

    Both files are normalised alike (lines of the kinds the tool inserts, ``G92 E…``,
    ``G1 C…`` and its comment block, are set aside; rotary words are removed), then the
    original lines are looked for in order: a line outside ``may_change`` must be found
    further on; a line in ``may_change`` (the part's extrusions) may be missing, and is
    only looked for within the next 64 lines so that it never jumps ahead to an identical
    line elsewhere.

    Returns
    -------
    (missing, changed)
        Lines outside ``may_change`` not found (must be empty), and lines of
        ``may_change`` not kept.
    """
    def norm(data: bytes) -> tuple[list[bytes], list[int]]:
        lines, where = [], []
        for i, ln in enumerate(data.splitlines(keepends=True)):
            if _INSERTED.match(ln):
                continue
            lines.append(_C_WORD.sub(b"", ln))
            where.append(i)
        return lines, where

    a, ia = norm(old)
    b, _ = norm(new)
    positions: dict[bytes, list[int]] = defaultdict(list)
    for j, ln in enumerate(b):
        positions[ln].append(j)
    ptr = 0
    missing: list[int] = []
    changed: list[int] = []
    for ln, i in zip(a, ia, strict=True):
        pos = positions.get(ln, [])
        k = bisect.bisect_left(pos, ptr)
        j = pos[k] if k < len(pos) else None
        if i in may_change:
            if j is not None and j < ptr + 64:
                ptr = j + 1
            else:
                changed.append(i)
        elif j is None:
            missing.append(i)
        else:
            ptr = j + 1
    return missing, changed


def geos_targets(g, filament_diameter: float = 1.75, quad_segs: int = 32) -> list:
    """Per layer, G rebuilt by GEOS from the file's part beads (None: no bead): the
    independent reference the deposition checks measure against."""
    from printability.settings import Settings
    from printability.sources.gcode import layer_regions

    out: list = [None] * len(g.layers)
    for li, geom, _facts in layer_regions(g, settings=Settings(quad_segs=quad_segs),
                                          filament_diameter=filament_diameter):
        out[li] = geom if geom is not None and not geom.is_empty else None
    return out
