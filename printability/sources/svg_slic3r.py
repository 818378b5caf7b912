"""Slic3r's multi-layer slice SVG (``slic3r --export-svg``), read as a layer stack.

Recognised by its ``xmlns:slic3r`` namespace and ``<g slic3r:z=...>`` layers;
the two writer generations and how layer tops are reconstructed are described
in :mod:`printability.sources.svg`.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon

from printability.errors import FileFormatError, excerpt
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack
from printability.settings import Settings
from printability.sources._common import (
    SVG_NUMBER,
    apply_fit,
    lazy_import,
    nest_even_odd,
    unit_scale,
    xml_local_name,
)

__all__ = ["SLIC3R_NS", "is_slic3r_svg", "slic3r_stack"]

SLIC3R_NS = "http://slic3r.org/namespaces/slic3r"


def is_slic3r_svg(root: Any) -> bool:
    """True for a Slic3r multi-layer slice SVG (``<g slic3r:z=...>`` layers)."""
    z_attr = f"{{{SLIC3R_NS}}}z"
    return any(z_attr in g.attrib for g in root.iter() if xml_local_name(g.tag) == "g")


def _points_attr(path: Path, text: str, where: str) -> np.ndarray:
    nums = SVG_NUMBER.findall(text or "")
    if len(nums) % 2 or len(nums) < 6:
        raise FileFormatError(path, f"expected at least 3 'x,y' points; found {len(nums)} "
                              "numbers", element=where)
    return np.array(nums, dtype=float).reshape(-1, 2)


def _path_rings(path: Path, d: str, where: str) -> list[np.ndarray]:
    """Rings of a polygonal path ``d`` (M/L/Z, absolute, as Slic3r writes it)."""
    if re.search(r"[^MmLlZz0-9eE+\-.,\s]", d):
        se = lazy_import("svgelements", "svg", "SVG paths with curves")
        rings = []
        for sp in se.Path(d).as_subpaths():
            pts = [(s.end.x, s.end.y) for s in sp if s.end is not None]
            if len(pts) >= 3:
                rings.append(np.array(pts, dtype=float))
        return rings
    if re.search(r"[ml]", d):
        raise FileFormatError(path, "relative path commands (m, l) are not expected in a "
                              "Slic3r slice SVG", element=where)
    rings = []
    for chunk in re.split(r"[Mm]", d):
        nums = SVG_NUMBER.findall(chunk)
        if not nums:
            continue
        if len(nums) % 2:
            raise FileFormatError(path, "expected pairs of coordinates in the path data",
                                  element=where)
        a = np.array(nums, dtype=float).reshape(-1, 2)
        if len(a) >= 3:
            rings.append(a)
    return rings


def slic3r_stack(path: Path, root: Any, *, units: str | None, fit: float | None,
                  settings: Settings) -> LayerStack:
    z_attr = f"{{{SLIC3R_NS}}}z"
    type_attr = f"{{{SLIC3R_NS}}}type"
    k = unit_scale(units)
    zs: list[float] = []
    regions: list[Any] = []
    writers: set[str] = set()
    skipped_groups = 0
    support = 0
    for gi, g in enumerate(e for e in root.iter() if xml_local_name(e.tag) == "g"):
        gid = g.get("id") or f"g[{gi}]"
        where = f"<g id={excerpt(gid, 40)}>"
        if z_attr not in g.attrib:
            skipped_groups += 1
            continue
        try:
            z = float(g.get(z_attr))
        except ValueError:
            raise FileFormatError(path, f"expected a number in slic3r:z; found "
                                  f"{excerpt(g.get(z_attr))}", element=where) from None
        if not math.isfinite(z):
            raise FileFormatError(path, "slic3r:z is not finite", element=where)
        rings: list[np.ndarray] = []
        for el in g:
            tag = xml_local_name(el.tag)
            kind = el.get(type_attr, "")
            if kind == "support" or tag in ("line", "circle"):
                support += 1
                continue
            ewhere = f"{where} <{tag}>"
            if tag == "polygon":
                writers.add("perl")
                rings.append(_points_attr(path, el.get("points", ""), ewhere))
            elif tag == "path":
                writers.add("c++")
                rings.extend(_path_rings(path, el.get("d", ""), ewhere))
        polys = nest_even_odd([r * k for r in rings], min_area=settings.area_tolerance)
        if not polys:
            continue
        zs.append(z)
        regions.append(MultiPolygon(polys))
    if not zs:
        raise FileFormatError(path, "a Slic3r slice SVG with no layer holding a closed "
                              "outline; expected <g slic3r:z=...> groups with <polygon> or "
                              "<path> outlines")
    # Layers of several objects at one height are one layer.
    order = np.argsort(zs, kind="stable")
    merged: list[tuple[float, Any]] = []
    for i in order:
        if merged and abs(zs[i] - merged[-1][0]) < 1e-9:
            merged[-1] = (merged[-1][0], shapely.union(merged[-1][1], regions[i]))
        else:
            merged.append((zs[i], regions[i]))
    warnings: list[str] = []
    # Slic3r 1.3's writer multiplies the slicing plane, already in mm, by its scaling factor
    # (10^-6) once more: a stack whose top is under a micrometre while its outlines are
    # millimetres across is that, not a print.
    z_top = max(abs(z) for z, _ in merged)
    x0, y0, x1, y1 = MultiPolygon([p for _, r in merged for p in r.geoms]).bounds
    if 0.0 < z_top < 1e-3 and max(x1 - x0, y1 - y0) > 1e3 * z_top:
        merged = [(z * 1e6, r) for z, r in merged]
        warnings.append("slic3r:z is in units of 10⁻⁶ mm (Slic3r 1.3 writes the slicing "
                        "plane scaled twice); read as mm")
    mids = "perl" in writers and "c++" not in writers
    zvals = [z * k for z, _ in merged]
    tops: list[float] = []
    if mids:
        for i, z in enumerate(zvals):
            tops.append(2 * z if i == 0 else 2 * z - tops[-1])
        if any(b <= a for a, b in zip([0.0, *tops[:-1]], tops, strict=True)):
            warnings.append("slic3r:z read as mid-heights gave non-increasing layer tops; "
                            "layer tops taken half a layer above each slicing plane instead")
            gaps = np.diff([0.0, *zvals])
            tops = [z + g / 2 for z, g in zip(zvals, gaps, strict=True)]
    else:
        tops = zvals
    heights = np.diff([0.0, *tops]).tolist()
    all_geom = MultiPolygon([p for _, r in merged for p in r.geoms])
    f = 1.0
    if fit is not None:
        _, f = apply_fit(all_geom, fit)
    layers = []
    for i, ((_, reg), top, h) in enumerate(zip(merged, tops, heights, strict=True)):
        if f != 1.0:
            reg = shapely.affinity.scale(reg, f, f, origin=(0, 0))
        region = as_region(reg, name=f"{path}, layer {i} (z={top:g})")
        layers.append(Layer(z=float(top), height=float(h), region=region, index=i))
    meta = {
        "format": "slic3r-svg",
        "writer": "Slic3r <= 1.3 (polygons, slic3r:z = slicing plane)" if mids
        else "Slic3r C++ SVGExport (paths, slic3r:z = layer top)",
        "skipped_groups": skipped_groups,
        "support_elements": support,
        "scale": k * f,
        "warnings": warnings,
    }
    return LayerStack(tuple(layers), source=str(path), meta=meta)
