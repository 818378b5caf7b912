"""SVG drawings and Slic3r's multi-layer slice SVG.

Safety
    Every file is parsed with :mod:`defusedxml` first. Documents that declare
    XML entities (the "billion laughs" expansion bomb) or reference external
    entities (which read local files or URLs) are refused with a
    :class:`~printability.errors.FileFormatError`; SVG drawings never need them.
    Only then does :mod:`svgelements` read the document.

Ordinary drawings (one planar layer, z = 0, height 0)
    * Transforms, ``<use>``, basic shapes, paths with lines, arcs, quadratic
      and cubic Béziers are handled by svgelements; curves are flattened so no
      point of a curve is farther than ``settings.chord_tolerance`` mm from the
      polyline (bounds: cubic ¾·max|Δ²P|/n², quadratic ¼·max|Δ²P|/n², arcs
      r·(1 − cos(Δθ/2))).
    * **What is filled.** Every element with a visible fill (not ``none``, not
      fully transparent, not ``display:none``) is ink, whatever its colour; its
      region follows its ``fill-rule`` (``nonzero`` by default, ``evenodd``),
      computed exactly from winding numbers, so crossing subpaths are right.
      Open subpaths are closed for filling, as SVG renders them. Strokes are
      ignored, text and images too; ``<defs>``, ``<symbol>`` and clip paths
      are drawn only where ``<use>`` places them. The ink of all elements is
      united.
    * **Background rule** (the game-icons quirk): an element whose filled
      region covers at least 99.5 % of the canvas (viewBox), followed by other
      filled elements, is a page background, not part of the shape; it is
      dropped and a warning is recorded. A lone full-canvas element is kept.
    * **Outline drawings**: if nothing is filled but stroked elements have
      closed subpaths (CAD exports often draw outlines only), those outlines are
      filled with the even-odd rule and a warning says so.
    * **Axes**: SVG's y axis points down the page; the result has **y growing
      upward**, with the origin at the canvas's lower-left corner:
      (x, y) ↦ (x, H − y), H the canvas height.
    * **Units**: when the root ``width``/``height`` carry a physical unit
      (mm, cm, in, pt, pc, Q) the drawing keeps its true size. Otherwise
      (unitless, px, % or absent) one CSS pixel (= one user unit of an
      unscaled document) is taken as **1 mm** and a warning says so;
      ``units=`` names the unit of that pixel instead ("px" means 1/96 in).
      ``fit=MM`` finally scales the shape about the origin so the longest side
      of its bounding box is MM mm.

Limits (checked before the work, a :class:`~printability.errors.ResourceError` naming the
file and the element)
    A drawing may expand to at most :data:`MAX_ELEMENTS` elements, every
    ``<use>`` counting as a copy of what it refers to (nested ``<use>``
    multiply: 11 levels of ten copies are 10¹¹ elements in 1.4 kB), nested at
    most :data:`MAX_DEPTH` deep, holding at most :data:`MAX_SOURCE_POINTS`
    points; a ``<use>`` may not refer to its own ancestor; and its curves may
    flatten to at most :data:`MAX_VERTICES` points (a circle of radius 10¹²
    flattened to 2 µm would be billions). Within them a drawing reads in well
    under a minute.

Slic3r slice SVG (``slic3r --export-svg``), recognised by its
``xmlns:slic3r`` namespace and ``<g slic3r:z=...>`` layers
    Coordinates are already slicer millimetres with y up (no flip). Two writer
    generations exist: Slic3r ≤ 1.2 (Perl) writes ``<polygon slic3r:type=
    "contour"|"hole">`` and puts the **slicing plane (mid-height)** in
    ``slic3r:z``; later C++ writers emit ``<path d="M x y ... z">`` (even-odd)
    and put the **layer top** there. Layer tops and heights are reconstructed
    accordingly (mid-heights: t₀ = 2·z₀, tᵢ = 2·zᵢ − tᵢ₋₁). Support material
    (``<line>``, ``<circle slic3r:type="support">``) is not part of the target
    and is skipped; groups without ``slic3r:z`` (raft layers) too.
"""

from __future__ import annotations

import io
import math
import re
import warnings as _warnings  # "warnings" is the list of notes for the user
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon

from printability.errors import FileFormatError, ResourceError, excerpt
from printability.model.geometry import polygons_of
from printability.model.layers import LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import (
    apply_fit,
    check_positive,
    fill_rings,
    lazy_import,
    planar_stack,
    read_bytes,
    require_file,
    unit_scale,
    xml_local_name,
)
from printability.sources.svg_expansion import (
    MAX_DEPTH,
    MAX_ELEMENTS,
    MAX_SOURCE_POINTS,
    check_expansion,
)
from printability.sources.svg_slic3r import is_slic3r_svg, slic3r_stack

__all__ = ["BACKGROUND_COVERAGE", "MAX_DEPTH", "MAX_ELEMENTS", "MAX_SOURCE_POINTS", "MAX_VERTICES",
           "check_expansion", "is_slic3r_svg", "load_svg_layers", "load_svg_region"]

BACKGROUND_COVERAGE = 0.995
"""Fraction of the canvas an element must cover to count as a page background."""

MAX_VERTICES = 1_000_000
"""Most points the outlines may have once curves are flattened (counted as they are)."""

_SVG_NS = "http://www.w3.org/2000/svg"
# svgelements keeps a Python object per path segment and point: budget generously.
_BYTES_PER_INPUT_BYTE = 120.0
_PHYSICAL_MM = {"mm": 1.0, "cm": 10.0, "in": 25.4, "pt": 25.4 / 72, "pc": 25.4 / 6,
                "q": 0.25}
_LENGTH = re.compile(r"^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([a-zA-Z%]*)\s*$")


def _parse_xml(path: Path, raw: bytes) -> Any:
    """Parse with defusedxml; refuse entity declarations and external references."""
    dx = lazy_import("defusedxml", "svg", "SVG files safely")
    from defusedxml import ElementTree as DET

    try:
        return DET.fromstring(raw, forbid_dtd=False, forbid_entities=True, forbid_external=True)
    except dx.EntitiesForbidden as exc:
        raise FileFormatError(
            path, f"refused: the document declares the XML entity "
            f"{excerpt(str(exc.name), 40)}; entity declarations can expand without bound "
            "('billion laughs') or read other files, and SVG drawings do not need them",
            element="<!ENTITY>") from None
    except (dx.ExternalReferenceForbidden, dx.DTDForbidden) as exc:
        raise FileFormatError(
            path, "refused: the document references an external resource "
            f"({excerpt(str(exc), 120)}); external entities can read local files or URLs",
            element="<!DOCTYPE>") from None
    except DET.ParseError as exc:
        line = exc.position[0] if getattr(exc, "position", None) else None
        why = exc.msg if hasattr(exc, "msg") else excerpt(str(exc), 120)
        raise FileFormatError(path, f"expected well-formed XML (an SVG document); {why}",
                              line=line) from None


# ---------------------------------------------------------------- ordinary drawings

class _OutOfRange(ValueError):
    """A curve's control points are not finite or beyond 1e15 (the message says which)."""


class _TooManyPoints(ValueError):
    """Flattening the curves would give more than :data:`MAX_VERTICES` points."""


def _n_bezier(ctrl: np.ndarray, tol: float, k: float) -> int:
    # max deviation of the chord polyline ≤ k·max|Δ²P| / n²  (k = 3/4 cubic, 1/4 quadratic)
    if not (np.abs(ctrl) <= 1e15).all():
        bad = ctrl[~(np.abs(ctrl) <= 1e15)].flat[0]
        raise _OutOfRange("not finite" if not math.isfinite(bad) else f"out of range ({bad:g})")
    d2 = np.abs(ctrl[2:] - 2 * ctrl[1:-1] + ctrl[:-2])
    m = float(np.hypot(d2[:, 0], d2[:, 1]).max()) if len(d2) else 0.0
    return max(1, math.ceil(math.sqrt(k * m / tol))) if m > 0 else 1


def _n_arc(r: float, sweep: float, tol: float) -> int:
    # chord error r·(1 − cos(Δθ/2)) ≤ tol; for tol ≪ r (where 1 − tol/r rounds to 1 and
    # acos gives 0) the small-angle form Δθ = √(8·tol/r)
    if not (math.isfinite(r) and math.isfinite(sweep)):
        raise _OutOfRange("not finite")
    if r <= tol or sweep == 0:
        return 1
    ratio = tol / r
    step = 2 * math.acos(1 - ratio) if ratio > 1e-8 else math.sqrt(8 * ratio)
    return max(1, math.ceil(sweep / step))


def _flatten_subpath(sp: Any, se: Any, tol: float, budget: list[int]) -> tuple[np.ndarray, bool]:
    """Points of one subpath, curves flattened within ``tol``; ``budget[0]`` is the number
    of points still allowed (counted before each curve is flattened)."""
    pts: list[tuple[float, float]] = []
    closed = False

    def take(n: int) -> None:
        budget[0] -= n
        if budget[0] < 0:
            raise _TooManyPoints(n)

    for seg in sp:
        if isinstance(seg, se.Move):
            take(1)
            pts.append((seg.end.x, seg.end.y))
        elif isinstance(seg, se.Close):
            closed = True
        elif isinstance(seg, se.Line):
            take(1)
            pts.append((seg.end.x, seg.end.y))
        elif isinstance(seg, (se.CubicBezier, se.QuadraticBezier)):
            cubic = isinstance(seg, se.CubicBezier)
            known = ((seg.start, seg.control1, seg.control2, seg.end) if cubic
                     else (seg.start, seg.control, seg.end))
            if any(p is None for p in known):
                # a curve with no current point ("T 0 0" first): SVG draws nothing before
                # an M; keep its end, as a line
                if seg.end is not None:
                    take(1)
                    pts.append((seg.end.x, seg.end.y))
                continue
            ctrl = np.array([[p.x, p.y] for p in known])
            n = _n_bezier(ctrl, tol, 0.75 if cubic else 0.25)
            take(n)
            xy = seg.npoint(np.linspace(0.0, 1.0, n + 1)[1:])
            pts.extend(map(tuple, np.asarray(xy, dtype=float)))
        elif isinstance(seg, se.Arc) and seg.start is not None and seg.end is not None:
            n = _n_arc(max(abs(seg.rx), abs(seg.ry)), abs(float(seg.sweep)), tol)
            take(n)
            xy = seg.npoint(np.linspace(0.0, 1.0, n + 1)[1:])
            pts.extend(map(tuple, np.asarray(xy, dtype=float)))
        elif seg.end is not None:
            take(1)
            pts.append((seg.end.x, seg.end.y))
    a = np.array(pts, dtype=float).reshape(-1, 2)
    if not (np.abs(a) <= 1e15).all():  # a line or a shape's corner (rect height="1e309")
        bad = a[~(np.abs(a) <= 1e15)].flat[0]
        raise _OutOfRange("not finite" if not math.isfinite(bad) else f"out of range ({bad:g})")
    if len(a) and not closed:
        closed = bool(np.allclose(a[0], a[-1]))
    return a, closed


def _visible_fill(el: Any) -> bool:
    fill = el.fill
    if fill is None or fill.value is None or fill.alpha == 0:
        return False
    for key in ("fill-opacity", "opacity"):
        v = el.values.get(key)
        try:
            if v is not None and float(v) == 0:
                return False
        except ValueError:
            pass
    return str(el.values.get("visibility", "visible")).strip() not in ("hidden", "collapse")


def _doc_scale(root: Any, svg: Any, units: str | None, warnings: list[str]) -> float:
    """mm per svgelements px (svgelements maps the viewBox onto width × height in px)."""
    if units is not None:
        return unit_scale(units)
    for attr, px in (("width", svg.width), ("height", svg.height)):
        v = root.get(attr)
        m = _LENGTH.match(v) if v else None
        if m and m.group(2).lower() in _PHYSICAL_MM and px:
            # From the document's own numbers, not svgelements' rounded px-per-mm.
            return float(m.group(1)) * _PHYSICAL_MM[m.group(2).lower()] / float(px)
    warnings.append("the SVG gives no physical size (width/height without mm, cm or in): "
                    "one px (user unit) was taken as 1 mm; pass units= or fit= to say otherwise")
    return 1.0


def _hide_symbols(root: Any, raw: bytes) -> bytes:
    """Move ``<symbol>`` elements into ``<defs>``: drawn only where a ``<use>`` places them.

    svgelements 1.9 renders a symbol's children in place as well; inside
    ``<defs>`` it does not, and ``<use>`` still finds them.
    """
    import xml.etree.ElementTree as ET

    parent = {c: p for p in root.iter() for c in p}
    loose = [e for e in root.iter() if xml_local_name(e.tag) == "symbol"
             and not any(xml_local_name(a.tag) == "defs" for a in _ancestors(e, parent))]
    if not loose:
        return raw
    defs = ET.SubElement(root, f"{{{_SVG_NS}}}defs")
    for e in loose:
        parent[e].remove(e)
        defs.append(e)
    ET.register_namespace("", _SVG_NS)
    ET.register_namespace("xlink", "http://www.w3.org/1999/xlink")
    return ET.tostring(root)


def _ancestors(e: Any, parent: dict[Any, Any]) -> list[Any]:
    out = []
    while e in parent:
        e = parent[e]
        out.append(e)
    return out


def _drawing_stack(path: Path, raw: bytes, root: Any, *, units: str | None,
                   fit: float | None, settings: Settings) -> LayerStack:
    se = lazy_import("svgelements", "svg", "SVG files")
    warnings: list[str] = []
    check_expansion(path, root)  # before svgelements copies every <use>
    raw = _hide_symbols(root, raw)
    try:
        svg = se.SVG.parse(io.BytesIO(raw), reify=True, ppi=96.0)
    except Exception as exc:  # svgelements raises many types on bad documents
        raise FileFormatError(path, f"the SVG could not be interpreted "
                              f"({type(exc).__name__}: {excerpt(str(exc), 120)})") from None
    if not isinstance(svg, se.SVG):
        raise FileFormatError(path, "the SVG could not be interpreted (svgelements found no "
                              "<svg> element in it)", element="<svg>")
    mm_per_px = _doc_scale(root, svg, units, warnings)
    if not (1e-12 <= mm_per_px <= 1e12):
        # width="1e308mm" or a viewBox of 1e308: every later length divides or overflows
        raise FileFormatError(path, f"the document's size and viewBox give {mm_per_px:g} mm per "
                              "user unit; expected a finite, non-zero scale (check the <svg> "
                              "width, height and viewBox)", element="<svg>")
    canvas_w = float(svg.width) if svg.width else 0.0
    canvas_h = float(svg.height) if svg.height else 0.0
    shapes = [e for e in svg.elements() if isinstance(e, se.Shape)]
    ignored = sum(1 for e in svg.elements() if isinstance(e, (se.Text, se.Image)))
    if ignored:
        warnings.append(f"{ignored} text or image element(s) ignored (only shapes are read)")
    # Tolerance in px, tightened by the fit scale estimated from the shapes' bounding boxes
    # (only with fit: svgelements takes about a millisecond per arc for a box).
    boxes = []
    if fit is not None:
        # an overflowing box (coordinates near 1e308) is refused below, point by point
        with np.errstate(all="ignore"), _warnings.catch_warnings():
            _warnings.simplefilter("ignore", RuntimeWarning)
            boxes = [b for b in (e.bbox() for e in shapes) if b is not None]
    scale = mm_per_px
    if boxes:
        b = np.array(boxes, dtype=float)
        longest = max(b[:, 2].max() - b[:, 0].min(), b[:, 3].max() - b[:, 1].min())
        if longest > 0:
            scale = fit / longest
    tol = settings.chord_tolerance / scale

    filled: list[tuple[str, Any]] = []
    outlines: list[np.ndarray] = []
    budget = [MAX_VERTICES]  # points left once curves are flattened
    for idx, el in enumerate(shapes):
        p = abs(se.Path(el))  # abs() applies the element's transform to its segments
        fill_ok = _visible_fill(el)
        stroke_ok = el.stroke is not None and el.stroke.value is not None
        if not (fill_ok or stroke_ok):
            continue
        rings = []
        element = f"<{xml_local_name(el.values.get('tag', 'path'))}> #{idx + 1}" + (
            f" id={excerpt(el.id, 40)}" if el.id else "")
        for sp in p.as_subpaths():
            try:
                a, closed = _flatten_subpath(sp, se, tol, budget)
            except _OutOfRange as exc:
                raise FileFormatError(path, f"a coordinate of this shape is {exc} (expected "
                                      "finite numbers up to 1e15)", element=element) from None
            except _TooManyPoints as exc:
                raise ResourceError(
                    f"{path}, {element}: flattening the curves of this drawing within "
                    f"{settings.chord_tolerance:g} mm would give more than {MAX_VERTICES:,} "
                    f"points (one of this shape's curves alone asks for {exc.args[0]:,}); nothing "
                    "was drawn. A curve this large for its tolerance is usually a units mistake: "
                    "check the drawing's size, or pass fit= / a coarser chord tolerance"
                ) from None
            if len(a) < 3:
                continue
            if fill_ok:
                rings.append(a)
            elif closed:
                outlines.append(a)
        if fill_ok and rings:
            rule = str(el.values.get("fill-rule", "nonzero")).strip().lower()
            rule = "evenodd" if rule == "evenodd" else "nonzero"
            reg = fill_rings(rings, rule)
            if not reg.is_empty and reg.area > 0:
                name = el.id or f"<{type(el).__name__.lower()}> #{idx + 1}"
                filled.append((name, reg))
    if len(filled) > 1 and canvas_w > 0 and canvas_h > 0:
        canvas = shapely.box(0, 0, canvas_w, canvas_h)
        name, first = filled[0]
        if first.intersection(canvas).area >= BACKGROUND_COVERAGE * canvas.area:
            warnings.append(f"the first filled element ({name}) covers the whole canvas and "
                            "is read as a page background, not part of the shape")
            filled = filled[1:]
    if filled:
        geom = shapely.union_all([g for _, g in filled])
    elif outlines:
        warnings.append("no filled element: the closed stroked outlines were filled "
                        "(even-odd) instead")
        geom = fill_rings(outlines, "evenodd")
    else:
        raise FileFormatError(path, "no closed shape: expected at least one filled element "
                              "(path, rect, circle, polygon...) or closed outline with area; "
                              f"found {len(shapes)} shape element(s), none enclosing area")
    # px → mm with y up, origin at the canvas's lower-left corner.
    if canvas_h <= 0:
        canvas_h = geom.bounds[3]
    geom = shapely.transform(geom, lambda c: np.column_stack(
        (c[:, 0] * mm_per_px, (canvas_h - c[:, 1]) * mm_per_px)))
    geom = shapely.make_valid(geom) if not geom.is_valid else geom
    if not polygons_of(geom):
        raise FileFormatError(path, "no closed shape with positive area")
    geom, f = apply_fit(geom, fit)
    meta = {"format": "svg", "scale": mm_per_px * f, "elements": len(filled),
            "canvas_mm": (canvas_w * mm_per_px * f, canvas_h * mm_per_px * f),
            "warnings": warnings}
    return planar_stack(geom, path=path, meta=meta, min_area=settings.area_tolerance)


def _read(path: str | Path, settings: Settings) -> tuple[Path, bytes, Any]:
    p = require_file(path)
    raw = read_bytes(p, factor=_BYTES_PER_INPUT_BYTE, limit=settings.max_memory,
                     what="parsing this SVG file")
    root = _parse_xml(p, raw)
    if xml_local_name(root.tag) != "svg":
        tag = xml_local_name(root.tag)
        raise FileFormatError(p, f"expected an <svg> root element; found <{tag}>",
                              element=f"<{tag}>")
    namespace = root.tag[1:].partition("}")[0] if root.tag.startswith("{") else _SVG_NS
    if namespace != _SVG_NS:
        # another vocabulary's <svg> (a mistyped xmlns): svgelements reads none of it as SVG
        raise FileFormatError(p, f"expected the SVG namespace xmlns=\"{_SVG_NS}\"; found "
                              f"{excerpt(namespace)}", element="<svg>")
    return p, raw, root


def load_svg_layers(
    path: str | Path,
    *,
    units: str | None = None,
    fit: float | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read an SVG file: a drawing (one planar layer) or a Slic3r slice SVG (many layers).

    Parameters
    ----------
    path
        The ``.svg`` file.
    units
        Unit of one px / user unit when the document gives no physical size
        (overrides the document's own when given); one of
        :data:`printability.options.UNITS`.
    fit
        Scale so the longest side of the shape's bounding box is ``fit`` mm.
    settings
        ``chord_tolerance`` (mm) bounds curve flattening; ``max_memory`` the parse.

    Returns
    -------
    LayerStack
        ``meta["warnings"]`` lists the assumptions made (units, background...).

    Raises
    ------
    FileFormatError
        Not XML, entity declarations or external references (refused), not an
        ``<svg>`` root, or no closed shape.
    """
    fit = check_positive("fit", fit)
    p, raw, root = _read(path, settings)
    if is_slic3r_svg(root):
        return slic3r_stack(p, root, units=units, fit=fit, settings=settings)
    return _drawing_stack(p, raw, root, units=units, fit=fit, settings=settings)


def load_svg_region(
    path: str | Path,
    *,
    units: str | None = None,
    fit: float | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> MultiPolygon:
    """The filled region of a planar SVG drawing, mm, y up (see :func:`load_svg_layers`).

    Raises
    ------
    FileFormatError
        As :func:`load_svg_layers`, and for a multi-layer slice SVG.
    """
    stack = load_svg_layers(path, units=units, fit=fit, settings=settings)
    if len(stack) != 1:
        raise FileFormatError(path, f"expected a single outline; this slice SVG has "
                              f"{len(stack)} layers")
    return stack[0].region

