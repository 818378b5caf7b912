"""Slicer dialects: layer markers, feature types, widths, flavour and slicer name.

Comments are found by a handful of regular expressions run over the whole
buffer (C speed) and mapped to line numbers with the line table; only
matches that start a line count (``G1 X1 ;TYPE:x`` is not a feature change).

=================  ==============================  =================  =======================
dialect            layer marker (and Z / height)   feature            width
=================  ==============================  =================  =======================
``prusa``          ``;LAYER_CHANGE`` ``;Z:``       ``;TYPE:``         ``;WIDTH:``
(PrusaSlicer,      ``;HEIGHT:``
SuperSlicer,
OrcaSlicer)
``bambu``          ``; CHANGE_LAYER``              ``; FEATURE:``     ``; LINE_WIDTH:``
                   ``; Z_HEIGHT:`` ``; LAYER_HEIGHT:``
``cura``           ``;LAYER:n``                    ``;TYPE:``         (none)
``simplify3d``     ``; layer n, Z = z``            ``; feature ...``  ``; tool H.. W..``
``zmoves``         none: layers from the Z of      (none)             (none)
                   extrusion moves
=================  ==============================  =================  =======================

Feature names are kept as written and also mapped to a small set of
categories (:data:`CATEGORIES`) so that callers can, e.g., leave supports
out of a part's region whatever the slicer called them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

__all__ = [
    "CATEGORIES",
    "NON_PART_CATEGORIES",
    "CommentInfo",
    "feature_category",
    "scan_comments",
]

_NUM = rb"([-+]?(?:\d+\.?\d*|\.\d+))"


def _rx(body: bytes) -> re.Pattern[bytes]:
    # No ^ anchor: a literal prefix lets the regex engine skip ahead fast;
    # matches that do not start a line are dropped by _lines_of.
    return re.compile(body, re.M)


_LAYER = {
    "prusa": _rx(rb";LAYER_CHANGE[ \t]*(?=[\r\n]|\Z)"),
    "bambu": _rx(rb"; CHANGE_LAYER[ \t]*(?=[\r\n]|\Z)"),
    "cura": _rx(rb";LAYER:[ \t]*(-?\d+)[ \t]*(?=[\r\n]|\Z)"),
    "simplify3d": _rx(rb"; layer (\d+), Z = " + _NUM),
}
_Z = {"prusa": _rx(rb";Z:[ \t]*" + _NUM), "bambu": _rx(rb"; Z_HEIGHT:[ \t]*" + _NUM)}
_HEIGHT = {
    "prusa": _rx(rb";HEIGHT:[ \t]*" + _NUM),
    "bambu": _rx(rb"; LAYER_HEIGHT:[ \t]*" + _NUM),
}
_FEATURE = {
    "prusa": _rx(rb";TYPE:[ \t]*([^\r\n]*)"),
    "cura": _rx(rb";TYPE:[ \t]*([^\r\n]*)"),
    "bambu": _rx(rb"; FEATURE:[ \t]*([^\r\n]*)"),
    "simplify3d": _rx(rb"; feature ([^\r\n]*)"),
}
_WIDTH = {
    "prusa": _rx(rb";WIDTH:[ \t]*" + _NUM),
    "bambu": _rx(rb"; LINE_WIDTH:[ \t]*" + _NUM),
    "simplify3d": _rx(rb"; tool H" + _NUM + rb" W" + _NUM),
}
_WIPE_START = _rx(rb"; ?WIPE_START")
_WIPE_END = _rx(rb"; ?WIPE_END")
_FLAVOR = (
    re.compile(rb";FLAVOR:[ \t]*([A-Za-z0-9_-]+)"),
    re.compile(rb"; gcode_flavor = ([A-Za-z0-9_-]+)"),
)
_SLICERS = (
    (re.compile(rb"SuperSlicer"), "SuperSlicer"),
    (re.compile(rb"OrcaSlicer"), "OrcaSlicer"),
    (re.compile(rb"BambuStudio"), "BambuStudio"),
    (re.compile(rb"PrusaSlicer"), "PrusaSlicer"),
    (re.compile(rb"Cura_SteamEngine|;Generated with Cura"), "Cura"),
    (re.compile(rb"Simplify3D"), "Simplify3D"),
    (re.compile(rb"[Ss]lic3r"), "Slic3r"),
)
_ARCWELDER = re.compile(rb"Postprocessed by \[ArcWelder\]")

CATEGORIES = (
    "outer_wall", "inner_wall", "overhang_wall", "solid_infill", "sparse_infill",
    "top_surface", "bottom_surface", "bridge", "gap_fill", "ironing", "support",
    "support_interface", "skirt", "brim", "wipe_tower", "custom", "other", "unknown",
)
"""Feature categories. ``unknown``: the file has no feature comments."""

NON_PART_CATEGORIES = frozenset(
    {"support", "support_interface", "skirt", "brim", "wipe_tower", "custom", "ironing"}
)
"""Categories whose material is not part of the printed object (or, for ironing,
adds none): left out of a layer's target region by default."""

_CATEGORY_OF = {
    # PrusaSlicer / SuperSlicer
    "external perimeter": "outer_wall",
    "perimeter": "inner_wall",
    "overhang perimeter": "overhang_wall",
    "internal infill": "sparse_infill",
    "solid infill": "solid_infill",
    "top solid infill": "top_surface",
    "bottom solid infill": "bottom_surface",
    "bridge infill": "bridge",
    "internal bridge infill": "bridge",
    "gap fill": "gap_fill",
    "thin wall": "outer_wall",
    "skirt/brim": "skirt",
    "skirt": "skirt",
    "brim": "brim",
    "support material": "support",
    "support material interface": "support_interface",
    "wipe tower": "wipe_tower",
    "ironing": "ironing",
    "custom": "custom",
    # OrcaSlicer / BambuStudio
    "outer wall": "outer_wall",
    "inner wall": "inner_wall",
    "overhang wall": "overhang_wall",
    "sparse infill": "sparse_infill",
    "internal solid infill": "solid_infill",
    "top surface": "top_surface",
    "bottom surface": "bottom_surface",
    "bridge": "bridge",
    "internal bridge": "bridge",
    "gap infill": "gap_fill",
    "support": "support",
    "support interface": "support_interface",
    "support transition": "support",
    "prime tower": "wipe_tower",
    "floating vertical shell": "solid_infill",
    # Cura
    "wall-outer": "outer_wall",
    "wall-inner": "inner_wall",
    "skin": "solid_infill",
    "fill": "sparse_infill",
    "support-interface": "support_interface",
    "support-infill": "support",
    "prime-tower": "wipe_tower",
    "raft": "support",
    # Simplify3D
    "outer perimeter": "outer_wall",
    "inner perimeter": "inner_wall",
    "solid layer": "solid_infill",
    "infill": "sparse_infill",
    "dense support": "support_interface",
    "prime pillar": "wipe_tower",
    "ooze shield": "wipe_tower",
}


def feature_category(name: str) -> str:
    """Category (one of :data:`CATEGORIES`) of a slicer's feature name."""
    return _CATEGORY_OF.get(name.strip().lower(), "other")


@dataclass(frozen=True, eq=False)
class CommentInfo:
    """What the comments of a file say. Line numbers are 0-based."""

    dialect: str
    slicer: str
    flavor: str | None
    arcwelder: bool
    layer_lines: np.ndarray  # int64, first line of each layer (its marker)
    layer_z: np.ndarray  # float64, NaN where the marker gives none
    layer_height: np.ndarray  # float64, NaN where the marker gives none
    feature_lines: np.ndarray  # int64
    feature_ids: np.ndarray  # int64 index into feature_names
    feature_names: tuple[str, ...]
    width_lines: np.ndarray  # int64
    width_values: np.ndarray  # float64
    wipe_start_lines: np.ndarray
    wipe_end_lines: np.ndarray


def _lines_of(pattern: re.Pattern[bytes], data: bytes, line_start: np.ndarray):
    ms = list(pattern.finditer(data))
    pos = np.fromiter((m.start() for m in ms), np.int64, len(ms))
    lines = np.searchsorted(line_start, pos, side="right") - 1
    at_start = line_start[lines] == pos
    if not at_start.all():
        lines = lines[at_start]
        ms = [m for m, keep in zip(ms, at_start.tolist(), strict=True) if keep]
    return lines, ms


def _decode(b: bytes) -> str:
    return b.decode("utf-8", errors="replace").strip()


def scan_comments(data: bytes, line_start: np.ndarray) -> CommentInfo:
    """Find the dialect's markers. ``line_start``: the tokeniser's line starts."""
    head = data[:65536] + b"\n" + data[-262144:]
    slicer = "unknown"
    for rx, name in _SLICERS:
        if rx.search(head):
            slicer = name
            break
    flavor = None
    for rx in _FLAVOR:
        # slicers write it in the header (Cura) or the settings block at the end
        m = rx.search(head)
        if m:
            flavor = m.group(1).decode("ascii", "replace").lower()
            break

    counts = {d: _lines_of(rx, data, line_start) for d, rx in _LAYER.items()}
    dialect = max(counts, key=lambda d: len(counts[d][1]))
    if len(counts[dialect][1]) == 0:
        dialect = "zmoves"
        layer_lines = np.zeros(0, np.int64)
        layer_z = np.zeros(0)
        layer_h = np.zeros(0)
    else:
        layer_lines, ms = counts[dialect]
        n = len(layer_lines)
        layer_z = np.full(n, np.nan)
        layer_h = np.full(n, np.nan)
        if dialect == "simplify3d":
            layer_z[:] = [float(m.group(2)) for m in ms]
        if dialect in _Z:
            for arr, rxs in ((layer_z, _Z), (layer_h, _HEIGHT)):
                zl, zm = _lines_of(rxs[dialect], data, line_start)
                owner = np.searchsorted(layer_lines, zl, side="right") - 1
                for o, m in zip(owner[::-1], zm[::-1], strict=True):  # first one wins
                    if o >= 0:
                        arr[o] = float(m.group(1))
    fam = "prusa" if dialect == "zmoves" else dialect
    feat_rx = _FEATURE.get(fam, _FEATURE["prusa"])
    feature_lines, fm = _lines_of(feat_rx, data, line_start)
    names: dict[str, int] = {}
    ids = np.empty(len(fm), np.int64)
    for k, m in enumerate(fm):
        ids[k] = names.setdefault(_decode(m.group(1)), len(names))
    width_lines = np.zeros(0, np.int64)
    width_values = np.zeros(0)
    if fam in _WIDTH:
        width_lines, wm = _lines_of(_WIDTH[fam], data, line_start)
        grp = 2 if fam == "simplify3d" else 1
        width_values = np.array([float(m.group(grp)) for m in wm], dtype=float)
    ws, _ = _lines_of(_WIPE_START, data, line_start)
    we, _ = _lines_of(_WIPE_END, data, line_start)
    return CommentInfo(
        dialect=dialect,
        slicer=slicer,
        flavor=flavor,
        arcwelder=bool(_ARCWELDER.search(head)),
        layer_lines=layer_lines,
        layer_z=layer_z,
        layer_height=layer_h,
        feature_lines=feature_lines,
        feature_ids=ids,
        feature_names=tuple(names),
        width_lines=width_lines,
        width_values=width_values,
        wipe_start_lines=ws,
        wipe_end_lines=we,
    )
