"""Layers from sliced G-code: each layer's target G rebuilt from its extrusions.

What the reconstruction is
--------------------------
Every extruding move of a layer (arcs linearised within
``settings.chord_tolerance``) is a *bead*: in plan view the set of points
within w/2 of the move's path, i.e. a rectangle of width w with
half-disc caps (a capsule). Consecutive moves that meet end to end with the
same width are buffered together as one polyline with round joins, which is
the same set as the union of their capsules. G is the union of all beads of
the layer (``shapely.buffer`` on arrays of polylines, then
``shapely.union_all``); caps and joins are polygons with
``settings.quad_segs`` segments per quarter circle, so G is inside the exact
union by at most (w/2)·(1 − cos(π/(4·quad_segs))).

The bead width w is, in this order of preference,

1. the slicer's own line width, from ``;WIDTH:`` (PrusaSlicer, SuperSlicer,
   OrcaSlicer), ``; LINE_WIDTH:`` (BambuStudio) or ``; tool H.. W..``
   (Simplify3D) comments;
2. otherwise derived from the filament the move feeds: a bead of cross-section
   area a over length L takes ΔE·A_f of filament (A_f = π·d_f²/4), so
   a = A_f·ΔE / L. Two cross-section models invert this:

   * ``"stadium"`` (Slic3r/PrusaSlicer's flow model: a rectangle with
     semicircular sides, height h = layer height):
     a = (w − h)·h + π·h²/4, so w = A_f·ΔE/(L·h) + h·(1 − π/4);
   * ``"rectangle"`` (CuraEngine's): a = w·h, so w = A_f·ΔE/(L·h).

   ``bead_model="auto"`` picks rectangle for Cura files and stadium for the
   rest. On the sample files these reproduce the slicers' stated widths: the
   stadium model matches PrusaSlicer's ``;WIDTH:`` to 2·10⁻⁵ mm, the
   rectangle model gives Cura's 0.4 mm line width to 10⁻⁴ mm.

What it cannot know
-------------------
* How the plastic really spreads: the bead is an idealised capsule; squish,
  corner bulges, over/under-extrusion and the slicer's intended overlap
  between neighbouring beads are not modelled (overlaps simply union).
* Regions the slicer left empty on purpose (sparse infill gaps) are holes of
  G exactly as printed: G is what the file deposits, not the CAD section.
  Interiors filled by sparse infill are therefore porous. With
  ``interior=True`` (:func:`layer_regions`, what the post-processor plans
  against) those gaps are filled back: a hole of G is the part's own (outside
  the object) when its boundary runs along the outer walls, and a gap inside
  the object otherwise (:func:`fill_interior`).
* Which moves are not part of the object, when the file does not say: by
  default the features in :data:`gcode.NON_PART_CATEGORIES` (supports and
  their interfaces, skirt, brim, wipe/prime tower, custom start/end
  G-code such as purge lines, and ironing, which adds no material) and
  moves inside ``WIPE_START``/``WIPE_END`` are left out; ``exclude=`` changes
  the set. A file without feature comments (old Slic3r, ArcWelder output)
  cannot tell a skirt or a support from the part, so they are included.
* Moves whose start position is unknown, zero-length moves and E-only
  moves lay no bead.
* Derived widths of very short moves are noisy (E is rounded to 5 decimals
  by slicers); widths above ``max_width_factor`` × the file's median derived width
  are clipped to it, and the number clipped is reported in ``meta``;
  derived widths are rounded to 1 µm.
* Infill the slicer combines over several layers ("combine infill every n
  layers"; OrcaSlicer's sample does it for sparse infill) is printed, thicker,
  in one layer of each group and appears only in that layer's G.
* Spiral (vase) layers, whose Z rises while extruding, are projected onto
  their layer's plane.
* In files without layer comments, layers come from the Z of the extrusions
  (see :mod:`gcode.reader`): a purge line printed at another Z than the
  first layer becomes a thin layer of its own, and the heights are the Z
  steps between layers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import shapely

from gcode import CATEGORIES, NON_PART_CATEGORIES, GCodeFile, read_gcode
from printability.base.arrays import take_rows
from printability.errors import FileFormatError, InputError
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import check_positive, require_file
from printability.sources.gcode_beads import (
    BEAD_MODELS,
    bead_widths,
    beads_union,
    chains,
    resolve_bead_model,
    segment_widths,
)

__all__ = ["BEAD_MODELS", "WALL_CATEGORIES", "bead_widths", "fill_interior", "layer_beads",
           "layer_regions", "load_gcode_layers", "resolve_bead_model", "segment_widths"]

def layer_beads(g: GCodeFile, **kwargs
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, str]:
    """The beads every layer target is the union of: one chord per row, in file order.

    Keyword arguments as :func:`load_gcode_layers` takes them.

    Returns
    -------
    (seg, width, derived, clipped, bounds, model)
        Chords (:meth:`GCodeFile.segments`, zero-length ones left out) and
        their widths as :func:`segment_widths` gives them; layer ``k``'s beads
        are rows ``bounds[k]:bounds[k + 1]`` (widths may be NaN or 0 there:
        such chords lay no bead); the bead model used.
    """
    return _layer_beads(g, **kwargs)[:6]


def _layer_beads(
    g: GCodeFile,
    *,
    settings: Settings = DEFAULT_SETTINGS,
    filament_diameter: float = 1.75,
    bead_model: str = "auto",
    use_width_comments: bool = True,
    exclude: Iterable[str] = NON_PART_CATEGORIES,
    max_width_factor: float = 3.0,
) -> tuple:
    """:func:`layer_beads`, and the row of ``g.moves`` each chord comes from."""
    excl = set(exclude)
    unknown = excl - set(CATEGORIES)
    if unknown:
        raise InputError(
            f"unknown feature categories {sorted(unknown)}; "
            f"expected some of {', '.join(CATEGORIES)}"
        )
    model = resolve_bead_model(g, bead_model)

    m = g.moves
    keep = m["is_extrusion"] & (m["layer"] >= 0) & ~g.moves_in(excl) & ~m["wipe"]
    idx = np.flatnonzero(keep)
    seg = g.segments(settings=settings, moves=take_rows(m, idx))
    mv = idx[seg["move"]]  # row of g.moves of each segment
    length = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"])
    ok = length > 0
    keep_ok = np.flatnonzero(ok)
    seg, mv = take_rows(seg, keep_ok), mv[keep_ok]
    layer = m["layer"][mv]
    width, derived, over = segment_widths(g, seg, mv, filament_diameter=filament_diameter,
                                          model=model, use_width_comments=use_width_comments,
                                          max_width_factor=max_width_factor)
    bounds = np.searchsorted(layer, np.arange(len(g.layers) + 1), side="left")
    return seg, width, derived, over, bounds, model, mv


def layer_regions(
    g: GCodeFile,
    *,
    settings: Settings = DEFAULT_SETTINGS,
    filament_diameter: float = 1.75,
    bead_model: str = "auto",
    use_width_comments: bool = True,
    exclude: Iterable[str] = NON_PART_CATEGORIES,
    max_width_factor: float = 3.0,
    interior: bool = False,
) -> list[tuple[int, object, dict]]:
    """Per layer: (layer index, shapely geometry of its beads or None, facts).

    See :func:`load_gcode_layers` for the parameters. Layers without any
    bead get ``None``. ``interior``: fill the gaps the slicer left inside the object
    (sparse infill) back into G, keeping the holes bounded by outer walls
    (:func:`fill_interior`); ``facts["interior_filled"]`` counts the gaps filled.
    """
    seg, width, derived, over, bounds, model, mv = _layer_beads(
        g, settings=settings, filament_diameter=filament_diameter, bead_model=bead_model,
        use_width_comments=use_width_comments, exclude=exclude,
        max_width_factor=max_width_factor)
    wall = g.moves_in(WALL_CATEGORIES)[mv] if interior else None

    def one(li: int) -> tuple[int, object, dict]:
        a, b = bounds[li], bounds[li + 1]
        facts: dict = {"beads": int(b - a), "width_from": "comments"}
        if b == a:
            return li, None, facts
        w = width[a:b]
        good = np.isfinite(w) & (w > 0)
        if derived[a:b].any():
            facts["width_from"] = f"extrusion ({model} bead)" if derived[a:b].all() else "both"
        facts["widths_clipped"] = int(over[a:b].sum())
        facts["median_width"] = float(np.median(w[good])) if good.any() else float("nan")
        if not good.any():
            return li, None, facts
        region = beads_union(seg[a:b][good], w[good], settings.quad_segs)
        if wall is not None:
            on = good & wall[a:b]
            key = np.column_stack([seg["x0"][a:b], seg["y0"][a:b], seg["x1"][a:b],
                                   seg["y1"][a:b], w, on]).tobytes()
            if key in filled:  # a layer repeating an earlier one to the bit (the cube's third)
                region, facts["interior_filled"] = filled[key]
            else:
                walls = _WallLines.of(seg[a:b][on], w[on]) if on.any() else None
                region, facts["interior_filled"] = filled[key] = fill_interior(region, walls)
        return li, region, facts

    filled: dict[bytes, tuple[object, int]] = {}
    return _map_layers(one, len(g.layers), settings)


WALL_CATEGORIES = frozenset({"outer_wall", "overhang_wall"})
"""Feature categories that trace the object's own boundary (:func:`fill_interior`)."""

_ALONG = 0.01
"""How near (mm) a hole's boundary must run to an outer wall to count as running along it."""
_SURE_OWN = 0.9
"""A hole whose boundary runs along the outer walls for this share of its length or more is
the object's own (or a hollow the slicer keeps on purpose: a vase, 0 % infill)."""
_SURE_GAP = 0.1
"""A hole whose boundary runs along the outer walls for less than this share is a gap
between infill lines and inner walls, inside the object."""


@dataclass(frozen=True)
class _WallLines:
    """A layer's outer walls as :func:`fill_interior` reads them: their centre lines (one
    line per chain), the largest half width, and the inside of their closed loops."""

    lines: object
    half_width: float
    inside: object

    @staticmethod
    def of(seg: np.ndarray, width: np.ndarray) -> _WallLines:
        chain = chains(seg, np.zeros(len(seg)))
        first = np.searchsorted(chain, np.arange(int(chain[-1]) + 2), side="left")
        lines, inside = [], None
        for c in range(len(first) - 1):
            a, b = first[c], first[c + 1]
            xy = np.concatenate([[[seg["x0"][a], seg["y0"][a]]],
                                 np.column_stack([seg["x1"][a:b], seg["y1"][a:b]])])
            lines.append(shapely.LineString(xy))
            # a chain closes when it ends within two bead widths of where it started
            # (slicers leave a small gap at the seam); the loops' inside is even-odd, so a
            # hole's loop within a contour's cuts it out
            if len(xy) >= 4 and math.hypot(*(xy[-1] - xy[0])) <= 2.0 * float(width[a:b].max()):
                loop = shapely.make_valid(shapely.Polygon(xy))
                inside = loop if inside is None else shapely.symmetric_difference(inside, loop)
        multi = shapely.MultiLineString(lines)
        shapely.prepare(multi)
        return _WallLines(multi, float(width.max()) / 2.0, inside)


def fill_interior(region, walls: _WallLines | None) -> tuple[object, int]:
    """``region`` with the gaps inside the object filled: (the region, gaps filled).

    A slicer traces every boundary of the object, outer contours and holes alike, with an
    outer wall (``;TYPE:External perimeter``, ``Outer wall``, ``WALL-OUTER``...). A hole of
    the bead union (``region``) is classified by the share of its boundary that runs along
    those walls (its edges whose ends lie within a wall's half width plus :data:`_ALONG` mm
    of a wall's centre line):

    * at least :data:`_SURE_OWN`: the object's own hole, or a hollow the slicer keeps on
      purpose (a vase, 0 % infill): kept;
    * under :data:`_SURE_GAP`: a gap between infill lines and inner walls: filled;
    * in between (a sliver between an outer and an inner wall, a sparse gap beside a single
      wall): filled only when it lies inside the walls' closed loops (even-odd), kept
      otherwise or when no loop closes.

    Material the nozzle lays in a filled gap is inside the part, which is all the MMC
    promise asks (the slicer's E, hence the volume, is unchanged). Without outer walls (a
    file with no feature comments) nothing is known and nothing is filled.

    Complexity: one distance test per vertex of the holes; no overlay unless a filled gap
    holds a separate piece of the object with holes of its own.
    """
    if walls is None or region is None or region.is_empty:
        return region, 0
    polys = shapely.get_parts(region)
    rings = [(i, r) for i, p in enumerate(polys) if p.geom_type == "Polygon"
             for r in p.interiors]
    if not rings:
        return region, 0
    share = np.empty(len(rings))
    for j, (_, r) in enumerate(rings):
        xy = np.asarray(r.coords)
        near = shapely.dwithin(shapely.points(xy), walls.lines, walls.half_width + _ALONG)
        seg_len = np.hypot(*np.diff(xy, axis=0).T)
        share[j] = seg_len[near[1:] & near[:-1]].sum() / max(seg_len.sum(), 1e-300)
    own = share >= _SURE_GAP
    unsure = np.flatnonzero(own & (share < _SURE_OWN))
    if unsure.size and walls.inside is not None and not walls.inside.is_empty:
        at = shapely.point_on_surface([shapely.Polygon(rings[j][1]) for j in unsure])
        own[unsure[shapely.contains(walls.inside, at)]] = False
    if own.all():
        return region, 0
    keep: dict[int, list] = {}
    for (i, r), k in zip(rings, own, strict=True):
        if k:
            keep.setdefault(i, []).append(r)
    gaps = [shapely.Polygon(rings[j][1]) for j in np.flatnonzero(~own)]
    # a piece of the region standing in a filled gap (an island) is now inside another
    tree = shapely.STRtree(gaps)
    at = shapely.point_on_surface(polys)
    island = np.zeros(len(polys), bool)
    pi, _ = tree.query(at, predicate="within")
    island[pi] = True
    if not any(island[i] and keep.get(i) for i in range(len(polys))):
        out = [shapely.Polygon(p.exterior, keep.get(i, [])) for i, p in enumerate(polys)
               if not island[i]]
        return (out[0] if len(out) == 1 else shapely.MultiPolygon(out)), len(gaps)
    # an island with holes of its own (a hole's walls standing in sparse infill): the gap
    # is filled around them
    kept = [shapely.Polygon(rings[j][1]) for j in np.flatnonzero(own)]
    kept_at = shapely.point_on_surface(kept)
    fills = []
    for gap in gaps:
        inner = [k for k, c in zip(kept, shapely.contains(gap, kept_at), strict=True)
                 if c and k.area < gap.area]
        fills.append(shapely.difference(gap, shapely.union_all(inner)) if inner else gap)
    return shapely.union_all([region, *fills]), len(gaps)


def _map_layers(fn, n: int, settings: Settings) -> list:
    """``[fn(i) for i in range(n)]``, on ``settings.workers`` threads (shapely
    releases the GIL in buffer and union), with a rich progress bar when
    ``settings.progress``."""
    progress = None
    task = None
    if settings.progress:
        from rich.progress import Progress

        progress = Progress(transient=True)
        progress.start()
        task = progress.add_task("rebuilding layers from G-code", total=n)
    try:
        out = []
        if settings.workers > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(settings.workers) as ex:
                for r in ex.map(fn, range(n)):
                    out.append(r)
                    if progress is not None:
                        progress.advance(task)
        else:
            for i in range(n):
                out.append(fn(i))
                if progress is not None:
                    progress.advance(task)
        return out
    finally:
        if progress is not None:
            progress.stop()


def load_gcode_layers(
    path: str | os.PathLike[str],
    *,
    settings: Settings = DEFAULT_SETTINGS,
    filament_diameter: float = 1.75,
    bead_model: str = "auto",
    use_width_comments: bool = True,
    exclude: Iterable[str] = NON_PART_CATEGORIES,
    flavor: str = "auto",
    max_width_factor: float = 3.0,
) -> LayerStack:
    """Read sliced G-code and rebuild every layer's target region G from its beads.

    G is the union of the layer's beads: each extruding move swept by a disc
    of the bead width (a rectangle with round caps in plan view). The width is
    the slicer's ``;WIDTH:``/``; LINE_WIDTH:`` when the file has it, else
    w = A_f·ΔE/(L·h) + h·(1 − π/4) (stadium cross-section, Slic3r family) or
    w = A_f·ΔE/(L·h) (rectangle, Cura), A_f = π·d_f²/4. G is what the file
    deposits, not the CAD section: sparse infill leaves holes, overlaps just
    union, squish and bulges are not modelled; supports, skirts, brims, wipe
    towers, purge lines and ironing are left out by default (only when the
    file labels them). Details and limits: the module docstring.

    Parameters
    ----------
    path
        The G-code file (any dialect :mod:`gcode.dialects` knows; files
        without layer comments get layers from the Z of their extrusions).
    settings
        ``chord_tolerance`` (arc linearisation, mm), ``quad_segs`` (bead caps
        and joins), ``max_memory``, ``progress``.
    filament_diameter
        d_f, mm, for widths derived from E.
    bead_model
        ``"auto"``, ``"stadium"`` or ``"rectangle"``: the bead cross-section
        used to turn E into a width when the file gives no width (module docs).
    use_width_comments
        Use the slicer's width comments when present (False: always derive
        widths from E).
    exclude
        Feature categories (:data:`gcode.CATEGORIES`) left out of G; default
        :data:`gcode.NON_PART_CATEGORIES`. Pass ``()`` to keep everything
        extruded (skirts, supports, purge lines...). Wipe moves never count.
    flavor
        Firmware flavour for E-mode semantics (``"auto"`` reads the file).
    max_width_factor
        Derived widths above this multiple of the file's median derived width
        are clipped to it.

    Returns
    -------
    LayerStack
        One :class:`Layer` per slicer layer with beads (z = the layer's top,
        height = its thickness), sorted by z; layers printed at the same z
        (a vase's closing layer, sequentially printed objects) are merged.
        ``meta`` holds the slicer, dialect, flavour, bead model, per-layer
        facts and the layers that had no part beads.

    Raises
    ------
    FileFormatError
        Unreadable G-code (see :func:`gcode.read_gcode`) or a file in which
        no layer has a part bead.

    Complexity: parsing is O(file size); each layer costs one buffer per
    polyline and one union, O(n log n) in its vertices.
    """
    p = require_file(path)
    check_positive("filament_diameter", filament_diameter)
    g = read_gcode(p, flavor=flavor, settings=settings)
    regions = layer_regions(
        g, settings=settings, filament_diameter=filament_diameter, bead_model=bead_model,
        use_width_comments=use_width_comments, exclude=exclude,
        max_width_factor=max_width_factor,
    )
    by_z: dict[float, list[tuple[int, object, dict]]] = {}
    empty: list[int] = []
    for li, geom, facts in regions:
        if geom is None or geom.is_empty or geom.area <= settings.area_tolerance:
            empty.append(li)
            continue
        by_z.setdefault(round(float(g.layers["z"][li]), 6), []).append((li, geom, facts))
    if not by_z:
        raise FileFormatError(
            p,
            "no layer has an extrusion that belongs to the part (all extrusions are "
            f"excluded features {sorted(set(exclude))} or the file extrudes nothing)",
        )
    layers: list[Layer] = []
    for k, z in enumerate(sorted(by_z)):
        items = by_z[z]
        geom = items[0][1] if len(items) == 1 else shapely.union_all([it[1] for it in items])
        src = [it[0] for it in items]
        height = float(max(g.layers["height"][i] for i in src))
        name = f"{p}, layer at z={z:g} mm"
        region = as_region(geom, name=name, min_area=settings.area_tolerance)
        meta = {"gcode_layers": src, "line": int(g.layers["line"][src[0]]) + 1,
                **items[0][2]}
        layers.append(Layer(z=z, height=height, region=region, index=k, meta=meta))
    model = resolve_bead_model(g, bead_model)
    meta = {
        "format": "gcode",
        "slicer": g.slicer,
        "dialect": g.dialect,
        "flavor": g.flavor,
        "arcwelder": g.arcwelder,
        "bead_model": model,
        "filament_diameter": filament_diameter,
        "excluded_features": sorted(set(exclude)),
        "gcode_layers": len(g.layers),
        "layers_without_part_beads": empty,
        "warnings": [*g.warnings, *_assumptions(g, regions, model, filament_diameter)],
    }
    return LayerStack(tuple(layers), source=str(p), meta=meta)


def _assumptions(g: GCodeFile, regions: list, model: str, filament_diameter: float) -> list[str]:
    """What the reconstruction had to assume for this file, in words."""
    out = []
    if g.dialect == "zmoves":
        out.append("no layer comments: layers taken from the Z of the extrusion moves")
    if not g.features:
        out.append(
            "no feature comments: skirts, brims, supports and purge lines cannot be told "
            "from the part and are included in the layers"
        )
    if any(f.get("width_from", "comments") != "comments" for _, _, f in regions):
        out.append(
            f"bead widths derived from E ({model} cross-section, filament diameter "
            f"{filament_diameter:g} mm) where the file gives no width"
        )
    clipped = sum(f.get("widths_clipped", 0) for _, _, f in regions)
    if clipped:
        out.append(f"{clipped} derived bead widths clipped as outliers")
    return out
