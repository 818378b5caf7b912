"""Slicer dialects: layer markers, feature types, widths, flavour and slicer name.

The dialect is chosen by counting its layer marker at line starts; then one
regular expression with a named branch per marker runs over the whole
buffer (C speed) and its matches are mapped to line numbers with the line
table; only matches that start a line count (``G1 X1 ;TYPE:x`` is not a
feature change).

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
    "INTERIOR_CATEGORIES",
    "NON_PART_CATEGORIES",
    "CommentInfo",
    "feature_category",
    "scan_comments",
]

_NUM = rb"[-+]?(?:\d+\.?\d*|\.\d+)"
_EOL = rb"[ \t]*(?=[\r\n]|\Z)"

# Per dialect: named branches of one regular expression (after a common ';'),
# so that a single pass over the buffer finds every marker. Group names: layer,
# lz (Z given with the layer marker), z, h, feature, width, wipe_start, wipe_end.
_BRANCHES = {
    "prusa": (
        rb"(?P<layer>LAYER_CHANGE" + _EOL + rb")",
        rb"Z:[ \t]*(?P<z>" + _NUM + rb")",
        rb"HEIGHT:[ \t]*(?P<h>" + _NUM + rb")",
        rb"TYPE:[ \t]*(?P<feature>[^\r\n]*)",
        rb"WIDTH:[ \t]*(?P<width>" + _NUM + rb")",
    ),
    "bambu": (
        rb"(?P<layer> CHANGE_LAYER" + _EOL + rb")",
        rb" Z_HEIGHT:[ \t]*(?P<z>" + _NUM + rb")",
        rb" LAYER_HEIGHT:[ \t]*(?P<h>" + _NUM + rb")",
        rb" FEATURE:[ \t]*(?P<feature>[^\r\n]*)",
        rb" LINE_WIDTH:[ \t]*(?P<width>" + _NUM + rb")",
    ),
    "cura": (
        rb"(?P<layer>LAYER:[ \t]*-?\d+" + _EOL + rb")",
        rb"TYPE:[ \t]*(?P<feature>[^\r\n]*)",
    ),
    "simplify3d": (
        rb"(?P<layer> layer \d+), Z = (?P<lz>" + _NUM + rb")",
        rb" feature (?P<feature>[^\r\n]*)",
        rb" tool H" + _NUM + rb" W(?P<width>" + _NUM + rb")",
    ),
}
_WIPE = (rb"(?P<wipe_start> ?WIPE_START)", rb"(?P<wipe_end> ?WIPE_END)")
# The ';' is outside the alternation: a literal prefix the regex engine finds
# with a fast scan (with ';' inside each branch the scan is ~50x slower).
_SCAN = {d: re.compile(b";(?:" + b"|".join((*br, *_WIPE)) + b")") for d, br in _BRANCHES.items()}
_SCAN["zmoves"] = _SCAN["prusa"]  # feature/width comments may still be there

# Layer markers at the start of a line, counted with bytes.count (memchr speed)
# to pick the dialect before the one full scan.
_MARKERS = {
    "prusa": b";LAYER_CHANGE",
    "bambu": b"; CHANGE_LAYER",
    "cura": b";LAYER:",
    "simplify3d": b"; layer ",
}
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

INTERIOR_CATEGORIES = frozenset(
    {"inner_wall", "solid_infill", "sparse_infill", "top_surface", "bottom_surface", "bridge",
     "gap_fill"}
)
"""Categories whose beads' edges are not the part's surface (walls inside the outer one,
infill, gap fill): such a bead may lie wider than planned inside the part (the outer wall,
an overhang, an unknown feature lays exactly the planned width)."""

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


def _decode(b: bytes) -> str:
    return b.decode("utf-8", errors="replace").strip()


def _pick_dialect(data: bytes, n_lines: int) -> str:
    # lines ending in a lone CR exist only if there are more lines than LFs
    lone_cr = n_lines > data.count(b"\n") + 1
    best, best_n = "zmoves", 0
    for d, marker in _MARKERS.items():
        n = data.count(b"\n" + marker) + data.startswith(marker)
        if lone_cr:
            n += data.count(b"\r" + marker)
        if n > best_n:
            best, best_n = d, n
    return best


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

    dialect = _pick_dialect(data, len(line_start) - 1)
    found: dict[str, list[tuple[int, bytes | None]]] = {
        k: [] for k in ("layer", "lz", "z", "h", "feature", "width", "wipe_start", "wipe_end")
    }
    matches = list(_SCAN[dialect].finditer(data))
    pos = np.fromiter((m.start() for m in matches), np.int64, len(matches))
    lines = np.searchsorted(line_start, pos, side="right") - 1
    at_start = (line_start[lines] == pos).tolist() if len(pos) else []
    for m, li, ok in zip(matches, lines.tolist(), at_start, strict=True):
        if not ok:
            continue  # a marker inside another line's comment does not count
        kind = m.lastgroup
        if kind == "lz":  # Simplify3D: "; layer 3, Z = 0.6" (lz closes last)
            found["lz"].append((li, m.group("lz")))
            kind = "layer"
        found[kind].append((li, None if kind in ("layer", "wipe_start", "wipe_end")
                            else m.group(kind)))

    def line_array(key: str) -> np.ndarray:
        return np.array([li for li, _ in found[key]], dtype=np.int64)

    layer_lines = line_array("layer")
    if len(layer_lines) == 0:
        dialect = "zmoves"
    n = len(layer_lines)
    layer_z = np.full(n, np.nan)
    layer_h = np.full(n, np.nan)
    for li, v in found["lz"]:
        layer_z[np.searchsorted(layer_lines, li)] = float(v)
    for arr, key in ((layer_z, "z"), (layer_h, "h")):
        if not found[key] or n == 0:
            continue
        owner = np.searchsorted(layer_lines, line_array(key), side="right") - 1
        for o, (_, v) in zip(owner[::-1].tolist(), found[key][::-1], strict=True):
            if o >= 0:  # iterating backwards: the first value after a marker wins
                arr[o] = float(v)
    names: dict[str, int] = {}
    ids = np.array(
        [names.setdefault(_decode(v), len(names)) for _, v in found["feature"]], dtype=np.int64
    )
    return CommentInfo(
        dialect=dialect,
        slicer=slicer,
        flavor=flavor,
        arcwelder=bool(_ARCWELDER.search(head)),
        layer_lines=layer_lines,
        layer_z=layer_z,
        layer_height=layer_h,
        feature_lines=line_array("feature"),
        feature_ids=ids,
        feature_names=tuple(names),
        width_lines=line_array("width"),
        width_values=np.array([float(v) for _, v in found["width"]], dtype=float),
        wipe_start_lines=line_array("wipe_start"),
        wipe_end_lines=line_array("wipe_end"),
    )
