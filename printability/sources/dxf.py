"""DXF drawings (via ezdxf): closed outlines of the model space, one planar layer.

What is read
    LWPOLYLINE and 2-D POLYLINE (bulges, i.e. arc segments, included), CIRCLE,
    ELLIPSE, ARC, LINE and SPLINE, also inside block references (INSERT,
    recursively). Curves are flattened within ``settings.chord_tolerance`` mm.
    Closed entities are rings as they are; open ones (ARC + LINE chains, open
    polylines and splines) are joined end to end into loops when their ends
    meet within ``join_tolerance`` mm. Pieces that do not close a loop are
    reported in ``meta["warnings"]`` and left out. Other entities (TEXT,
    DIMENSION, HATCH, 3-D entities...) are counted in ``meta["skipped"]``, and
    so are invisible entities and those on layers that are off or frozen
    (construction geometry). Paper space is not read.

Nesting
    Outlines are not marked as outer boundaries or holes: a loop inside an odd
    number of others is a hole (even-odd containment), as in the slice files.

Units
    ``$INSUNITS`` is honoured (inches, feet, cm, m, µm...); a drawing that says
    "unitless" (0) or nothing is read as mm with a warning, unless ``units=``
    says what it is. An explicit ``units=`` overrides the header (a warning
    records the disagreement).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from printability.errors import FileFormatError
from printability.model.layers import LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import (
    apply_fit,
    check_memory,
    check_positive,
    lazy_import,
    multipolygon,
    nest_even_odd,
    planar_stack,
    require_file,
    unit_scale,
)

__all__ = ["INSUNITS_NAMES", "load_dxf_layers"]

INSUNITS_NAMES = {
    0: "unitless", 1: "inches", 2: "feet", 3: "miles", 4: "millimeters", 5: "centimeters",
    6: "meters", 7: "kilometers", 8: "microinches", 9: "mils", 10: "yards", 11: "angstroms",
    12: "nanometers", 13: "microns", 14: "decimeters", 15: "decameters", 16: "hectometers",
    17: "gigameters", 18: "astronomical units", 19: "light years", 20: "parsecs",
}
_CURVES = ("LINE", "ARC", "CIRCLE", "ELLIPSE", "LWPOLYLINE", "POLYLINE", "SPLINE")
# ezdxf keeps a tag object per group code: budget ~80 bytes per input byte.
_BYTES_PER_INPUT_BYTE = 80.0
_MAX_BLOCK_DEPTH = 16


def _entities(layout: Any, depth: int = 0) -> Any:
    for e in layout:
        if e.dxftype() == "INSERT" and depth < _MAX_BLOCK_DEPTH:
            yield from _entities(e.virtual_entities(), depth + 1)
        else:
            yield e


def _flatten(e: Any, tol: float) -> np.ndarray:
    """Points along an entity, every chord within ``tol`` of the true curve.

    Native flattening keeps vertices on the circle/ellipse/spline itself
    (ezdxf's generic paths would first replace arcs by cubic Béziers, off by
    2.7e-4 × radius).
    """
    kind = e.dxftype()
    if kind == "LINE":
        pts = [e.dxf.start, e.dxf.end]
    elif kind in ("ARC", "CIRCLE"):
        pts = list(e.flattening(sagitta=tol))
    elif kind in ("ELLIPSE", "SPLINE"):
        pts = list(e.flattening(distance=tol))
    else:  # LWPOLYLINE, 2-D POLYLINE: straight and bulged (arc) segments
        pts = []
        for sub in e.virtual_entities():
            seg = _flatten(sub, tol)
            if len(pts) and len(seg) and np.allclose(pts[-1], seg[0], rtol=0, atol=1e-12):
                seg = seg[1:]
            pts.extend(map(tuple, seg))
        return np.array(pts, dtype=float).reshape(-1, 2)
    return np.array([(v[0], v[1]) for v in pts], dtype=float).reshape(-1, 2)


def _join(pieces: list[np.ndarray], tol: float) -> tuple[list[np.ndarray], int]:
    """Join open polylines whose ends meet within ``tol`` into closed rings.

    Returns the rings and the number of pieces left open.
    """
    from scipy.spatial import cKDTree

    if not pieces:
        return [], 0
    ends = np.array([[p[0], p[-1]] for p in pieces]).reshape(-1, 2)
    # Cluster end points (union-find over pairs closer than tol).
    parent = np.arange(len(ends))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in cKDTree(ends).query_pairs(tol):
        ri, rj = find(i), find(j)
        if ri != rj:
            parent[ri] = rj
    node = np.array([find(i) for i in range(len(ends))]).reshape(-1, 2)
    incident: dict[int, list[int]] = defaultdict(list)
    for k, (a, b) in enumerate(node):
        incident[int(a)].append(k)
        incident[int(b)].append(k)
    used = np.zeros(len(pieces), dtype=bool)
    rings = []
    n_joined = 0
    for k in range(len(pieces)):
        if used[k]:
            continue
        # Walk from piece k while every node on the way has exactly two pieces.
        chain = [pieces[k]]
        used[k] = True
        start, cur = int(node[k, 0]), int(node[k, 1])
        ok = len(incident[start]) == 2
        while ok and cur != start:
            nxt = [m for m in incident[cur] if not used[m]]
            if len(incident[cur]) != 2 or len(nxt) != 1:
                ok = False
                break
            m = nxt[0]
            used[m] = True
            if int(node[m, 0]) == cur:
                chain.append(pieces[m])
                cur = int(node[m, 1])
            else:
                chain.append(pieces[m][::-1])
                cur = int(node[m, 0])
        if ok:
            rings.append(np.vstack(chain))
            n_joined += len(chain)
    return rings, len(pieces) - n_joined


def _drawing_scale(p: Path, doc: Any, units: str | None,
                   warnings: list[str]) -> tuple[float, int]:
    """mm per drawing unit (``units`` when given, else the drawing's ``$INSUNITS``, else 1
    with a warning), and the ``$INSUNITS`` code."""
    from ezdxf import units as ezunits

    code = int(doc.header.get("$INSUNITS", 0) or 0)
    if units is not None:
        k = unit_scale(units)
        if code:
            try:
                header_k = ezunits.conversion_factor(code, ezunits.MM)
            except (KeyError, IndexError, ValueError):
                header_k = None
            if header_k is not None and abs(header_k - k) > 1e-9 * k:
                warnings.append(f"units={units!r} overrides the drawing's $INSUNITS "
                                f"{code} ({INSUNITS_NAMES.get(code, '?')})")
    elif code == 0:
        k = 1.0
        warnings.append("the drawing is unitless ($INSUNITS 0 or absent): read as mm; pass "
                        "units= to say otherwise")
    else:
        try:
            k = float(ezunits.conversion_factor(code, ezunits.MM))
        except (KeyError, IndexError, ValueError):
            raise FileFormatError(p, f"unknown $INSUNITS code {code}; expected one of "
                                  f"{sorted(INSUNITS_NAMES)}", element="$INSUNITS") from None
    return k, code


def load_dxf_layers(
    path: str | Path,
    *,
    units: str | None = None,
    fit: float | None = None,
    join_tolerance: float = 1e-3,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read the closed outlines of a DXF drawing as one planar layer.

    Parameters
    ----------
    path
        The ``.dxf`` file (ASCII or binary DXF).
    units
        Drawing unit, overriding ``$INSUNITS`` (one of :data:`printability.options.UNITS`).
    fit
        Scale so the longest side is ``fit`` mm.
    join_tolerance
        Largest gap between the ends of open pieces joined into a loop, mm.
    settings
        ``chord_tolerance`` (mm) bounds curve flattening; ``max_memory`` the parse.

    Returns
    -------
    LayerStack
        One layer; ``meta`` holds ``insunits``, ``scale`` (mm per drawing unit),
        ``skipped`` (entity types not read) and ``warnings``.

    Raises
    ------
    FileFormatError
        Not a DXF file, or no closed outline.
    """
    ezdxf = lazy_import("ezdxf", "dxf", "DXF files")

    p = require_file(path)
    fit = check_positive("fit", fit)
    join_tolerance = check_positive("join_tolerance", join_tolerance) or 1e-3
    check_memory(p, p.stat().st_size * _BYTES_PER_INPUT_BYTE, settings.max_memory,
                 "parsing this DXF file")
    try:
        doc = ezdxf.readfile(p)
    except ezdxf.DXFStructureError as exc:
        raise FileFormatError(p, f"expected a DXF drawing; {exc}") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise FileFormatError(p, f"expected a DXF drawing; found unreadable content ({exc})"
                              ) from None
    except OSError as exc:
        raise FileFormatError(p, f"expected a DXF drawing; {exc}") from None
    warnings: list[str] = []
    k, code = _drawing_scale(p, doc, units, warnings)
    tol = settings.chord_tolerance / k  # in drawing units
    rings: list[np.ndarray] = []
    pieces: list[np.ndarray] = []
    skipped: dict[str, int] = defaultdict(int)
    hidden = {layer.dxf.name.lower() for layer in doc.layers
              if layer.is_off() or layer.is_frozen()}
    for e in _entities(doc.modelspace()):
        kind = e.dxftype()
        if e.dxf.get("invisible", 0) or str(e.dxf.get("layer", "0")).lower() in hidden:
            skipped["hidden (invisible, or on a layer that is off or frozen)"] += 1
            continue
        if kind not in _CURVES:
            skipped[kind] += 1
            continue
        if kind == "POLYLINE" and not e.is_2d_polyline:
            skipped["POLYLINE (3-D, mesh or polyface)"] += 1
            continue
        try:
            pts = _flatten(e, tol)
        except (ValueError, TypeError, ZeroDivisionError, ArithmeticError) as exc:
            raise FileFormatError(p, f"cannot read this {kind} ({exc})",
                                  element=f"{kind} handle {e.dxf.handle}") from None
        if len(pts) < 2 or not np.isfinite(pts).all():
            continue
        closed = bool(getattr(e, "closed", False)) or kind in ("CIRCLE",) or (
            len(pts) > 2 and np.allclose(pts[0], pts[-1], atol=join_tolerance / k, rtol=0))
        if closed:
            if len(pts) >= 3:
                rings.append(pts)
        else:
            pieces.append(pts)
    joined, n_open = _join(pieces, join_tolerance / k)
    if n_open:
        warnings.append(f"{n_open} open piece(s) (lines, arcs, open polylines or splines) "
                        "do not close a loop and were left out")
    n_closed = len(rings)
    rings.extend(joined)
    polys = nest_even_odd([r * k for r in rings], min_area=settings.area_tolerance)
    if not polys:
        found = ", ".join(f"{n} {t}" for t, n in sorted(skipped.items())) or "none other"
        raise FileFormatError(
            p, "no closed outline: expected closed polylines, circles, ellipses or chains of "
            f"lines and arcs that close; found {n_closed} closed and {len(pieces)} "
            f"open curve(s) (other entities: {found})")
    geom, f = apply_fit(multipolygon(polys), fit)
    meta = {"format": "dxf", "insunits": code,
            "insunits_name": INSUNITS_NAMES.get(code, "?"), "scale": k * f,
            "skipped": dict(skipped), "loops_joined": len(joined), "warnings": warnings}
    return planar_stack(geom, path=p, meta=meta, min_area=settings.area_tolerance)

