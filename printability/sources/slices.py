"""Slice-outline text files (the Variable-width-contouring data set's format).

Format (``../shared/data/slices``)::

    0.3            minimal bead width, mm
    0.7            maximal bead width, mm
    28             point count of the first closed curve
    29.802 1020.23 one "x y" line per point, mm
    ...            further curves: count line, then points

Outer boundaries and holes are not marked: they are nested by even-odd
containment (a curve inside an odd number of others is a hole). The bead
widths are kept in ``LayerStack.meta["min_bead_width"]`` / ``["max_bead_width"]``.
The result is one planar layer (z = 0, height 0); the ``_z<number>`` tag of the
data set's file names (the slicing height in µm, it seems) is kept in
``meta["name_z_um"]`` without being interpreted.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from printability.errors import FileFormatError, excerpt
from printability.model.layers import LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import (
    MAX_COORDINATE,
    apply_fit,
    check_positive,
    multipolygon,
    nest_even_odd,
    planar_stack,
    read_bytes,
    require_file,
    unit_scale,
)

__all__ = ["load_slice_layers", "looks_like_slices"]

# Peak memory of a load per byte of the file, measured: 83-89 for files of many small curves
# (2-8 MB of 4-point squares: a curve's polygon, its nesting and its share of the union cost
# more than its ~60 bytes of text); the guard said 60.
_BYTES_PER_INPUT_BYTE = 120.0
_NAME_Z = re.compile(r"_z(\d+)$")


def looks_like_slices(head: bytes) -> bool:
    """True if the first bytes read like this format (two numbers, then a count)."""
    lines = head.decode("latin-1").splitlines()[:4]
    if len(lines) < 4:
        return False
    try:
        float(lines[0])
        float(lines[1])
        n = int(lines[2])
        x, y = lines[3].split()
        float(x), float(y)
    except ValueError:
        return False
    return n >= 0


def _number(path: Path, text: str, no: int, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise FileFormatError(path, f"expected {what}; found {excerpt(text.strip())}",
                              line=no) from None
    if not math.isfinite(v):
        raise FileFormatError(path, f"expected a finite {what}; found {excerpt(text.strip())}",
                              line=no)
    return v


def load_slice_layers(
    path: str | Path,
    *,
    units: str | None = None,
    fit: float | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read one slice-outline text file as a planar layer.

    Parameters
    ----------
    path
        The ``.txt`` file.
    units
        Unit of the coordinates (default ``"mm"``, as in the data set).
    fit
        If given, scale the outline so its longest side is ``fit`` mm.
    settings
        ``max_memory`` bounds the parse.

    Returns
    -------
    LayerStack
        One layer; ``meta`` holds ``min_bead_width`` and ``max_bead_width`` (mm,
        scaled with the outline) and ``curves`` (the number of curves).

    Raises
    ------
    FileFormatError
        A line that is not what the format expects there (named by number), a
        curve cut short, or no curve with area.
    """
    p = require_file(path)
    fit = check_positive("fit", fit)
    k = unit_scale(units)
    raw = read_bytes(p, factor=_BYTES_PER_INPUT_BYTE, limit=settings.max_memory,
                     what="reading this slice file")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise FileFormatError(p, "expected plain ASCII text (numbers); found binary data",
                              line=line) from None
    lines = text.splitlines()
    if len(lines) < 2:
        raise FileFormatError(p, "expected the minimal and maximal bead widths on lines 1 "
                              f"and 2; the file has {len(lines)} line(s)")
    wmin = _number(p, lines[0], 1, "the minimal bead width (mm)")
    wmax = _number(p, lines[1], 2, "the maximal bead width (mm)")
    if not (0 < wmin <= wmax):
        raise FileFormatError(p, f"expected 0 < minimal bead width <= maximal; found {wmin:g} "
                              f"and {wmax:g}", line=2)
    rings = []
    i = 2
    n_lines = len(lines)
    while i < n_lines:
        head = lines[i].strip()
        if not head:
            i += 1
            continue
        try:
            count = int(head)
        except ValueError:
            raise FileFormatError(p, f"expected a point count (an integer) starting a curve; "
                                  f"found {excerpt(head)}", line=i + 1) from None
        if count < 0:
            raise FileFormatError(p, f"expected a non-negative point count; found {count}",
                                  line=i + 1)
        start = i + 1
        if start + count > n_lines:
            raise FileFormatError(
                p, f"the curve announces {count} points but the file ends after "
                f"{n_lines - start} (truncated?)", line=i + 1)
        block = lines[start : start + count]
        try:
            pts = np.array([ln.split() for ln in block], dtype=float)
        except ValueError:
            # Find the culprit line for the message.
            for j, ln in enumerate(block):
                fields = ln.split()
                ok = len(fields) == 2
                if ok:
                    try:
                        float(fields[0]), float(fields[1])
                    except ValueError:
                        ok = False
                if not ok:
                    raise FileFormatError(p, f"expected a point 'x y' (two numbers); found "
                                          f"{excerpt(ln.strip())}", line=start + j + 1) from None
            raise
        if count and (pts.ndim != 2 or pts.shape[1] != 2):
            raise FileFormatError(p, "expected one point 'x y' per line", line=start + 1)
        in_range = np.abs(pts) <= MAX_COORDINATE  # False for nan too
        if count and not in_range.all():
            bad = int(np.argmax(~in_range.all(axis=1)))
            raise FileFormatError(p, f"expected finite coordinates up to {MAX_COORDINATE:g}; found "
                                  f"{excerpt(block[bad].strip())}", line=start + bad + 1)
        if count >= 3:
            rings.append(pts * k)
        i = start + count
    polys = nest_even_odd(rings, min_area=settings.area_tolerance)
    if not polys:
        raise FileFormatError(p, f"no closed curve with positive area among {len(rings)} "
                              "curve(s); expected point-count lines followed by 'x y' lines")
    geom, f = apply_fit(multipolygon(polys), fit)
    meta = {
        "format": "slices",
        "min_bead_width": wmin * k * f,
        "max_bead_width": wmax * k * f,
        "curves": len(rings),
        "scale": k * f,
        "warnings": [],
    }
    m = _NAME_Z.search(p.stem)
    if m:
        meta["name_z_um"] = int(m.group(1))
    return planar_stack(geom, path=p, meta=meta)
