"""How much an SVG drawing expands to, counted before any of it is built.

Every ``<use>`` counts as a copy of what it refers to (nested ``<use>``
multiply: 11 levels of ten copies are 10¹¹ elements in 1.4 kB), so the counts
are made over the element tree once per element, never by expanding it; a
drawing over :data:`MAX_ELEMENTS`, :data:`MAX_SOURCE_POINTS` or
:data:`MAX_DEPTH` is refused naming the element that expands most (see
:mod:`printability.sources.svg`, "Limits").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from printability.errors import FileFormatError, ResourceError, excerpt
from printability.sources._common import SVG_NUMBER, xml_local_name

__all__ = ["MAX_DEPTH", "MAX_ELEMENTS", "MAX_SOURCE_POINTS", "check_expansion"]

MAX_ELEMENTS = 10_000
"""Most elements a drawing may expand to, ``<use>`` copies included (reading costs about
2 ms per element: 10 000 take some 20 s)."""

MAX_SOURCE_POINTS = 250_000
"""Most points (pairs of numbers in ``d`` and ``points``; four per basic shape) the drawn
document may hold, ``<use>`` copies included: svgelements reads path data at some 20 µs a
number, and every point is then transformed and flattened (about 20 s for this many)."""

MAX_DEPTH = 200
"""Deepest nesting of elements (``<g>`` in ``<g>``..., ``<use>`` included) a drawing may have."""


_XLINK_HREF = "{http://www.w3.org/1999/xlink}href"
# Elements whose content is drawn only where a <use> (or a reference) places it.
_NOT_DRAWN = frozenset({"defs", "symbol", "clipPath", "mask", "pattern", "marker",
                        "linearGradient", "radialGradient", "filter", "style", "script",
                        "title", "desc", "metadata"})
# Points of a basic shape before curves are flattened (curves are counted as flattened).
_SHAPE_POINTS = {"rect": 4, "circle": 4, "ellipse": 4, "line": 2}


def _name(el: Any) -> str:
    """``<use href="#a11">``, ``<path id="outline">`` or ``<rect>``: an element for messages."""
    tag = xml_local_name(el.tag)
    for key in ("id", _XLINK_HREF, "href"):
        value = el.get(key)
        if value is not None:
            attr = "id" if key == "id" else "href"
            return f"<{tag} {attr}={excerpt(value, 40)}>"
    return f"<{tag}>"


def _own_points(el: Any) -> int:
    tag = xml_local_name(el.tag)
    if tag == "path":
        return len(SVG_NUMBER.findall(el.get("d", ""))) // 2
    if tag in ("polygon", "polyline"):
        return len(SVG_NUMBER.findall(el.get("points", ""))) // 2
    return _SHAPE_POINTS.get(tag, 0)


def check_expansion(path: Path, root: Any) -> tuple[int, int]:
    """Count what a drawing expands to before any of it is built: elements and points,
    every ``<use>`` counting as a copy of what it refers to.

    Returns
    -------
    elements, points
        Totals of the drawn document (the content of ``<defs>``, ``<symbol>``...
        counts where a ``<use>`` places it; curves count their control points).

    Raises
    ------
    ResourceError
        More than :data:`MAX_ELEMENTS` elements, :data:`MAX_SOURCE_POINTS` points or
        :data:`MAX_DEPTH` levels; the message names the element that expands most.
    FileFormatError
        A ``<use>`` refers to its own ancestor (the drawing would contain itself).
    """
    ids = {el.get("id"): el for el in root.iter() if el.get("id") is not None}

    def parts(el: Any) -> list[Any]:
        out = [c for c in el if isinstance(c.tag, str) and xml_local_name(c.tag) not in _NOT_DRAWN]
        if xml_local_name(el.tag) == "use":
            ref = el.get(_XLINK_HREF) or el.get("href") or ""
            target = ids.get(ref[1:]) if ref.startswith("#") else None
            if target is not None:
                out.append(target)
        return out

    # Per element: (elements, points, depth) of one drawn copy, each element once (10^11 is
    # only a number here); an iterative depth-first walk: a deep document must not exhaust
    # Python's recursion.
    size: dict[Any, tuple[int, int, int]] = {}
    on_path: set[Any] = set()
    stack: list[tuple[Any, bool, Any]] = [(root, False, root)]  # (element, done, reached from)
    while stack:
        el, done, via = stack.pop()
        if done:
            on_path.discard(el)
            kids = [size[k] for k in parts(el)]
            size[el] = (1 + sum(k[0] for k in kids), _own_points(el) + sum(k[1] for k in kids),
                        1 + max((k[2] for k in kids), default=0))
            continue
        if el in size:
            continue
        if el in on_path:
            raise FileFormatError(path, f"refers to {_name(el)}, which contains it: the drawing "
                                  "would contain itself without end; expected a <use> of an "
                                  "element outside it", element=_name(via))
        on_path.add(el)
        stack.append((el, True, via))
        stack.extend((k, False, el) for k in parts(el) if k not in size)
    if _over(size[root]):
        # too deep: the whole document is; too many: the element that multiplies them
        el = root if size[root][2] > MAX_DEPTH else _culprit(root, parts, size)
        _refuse_expansion(path, el, size)
    return size[root][:2]


def _over(counts: tuple[int, int, int]) -> bool:
    n, v, d = counts
    return n > MAX_ELEMENTS or v > MAX_SOURCE_POINTS or d > MAX_DEPTH


def _culprit(el: Any, parts: Any, size: dict[Any, tuple[int, int, int]]) -> Any:
    """The element to name: the deepest one over a limit, following children (a ``<use>``
    is named rather than what it refers to, which may be anywhere)."""
    while xml_local_name(el.tag) != "use":
        over = [k for k in parts(el) if k in size and _over(size[k])]
        if not over:
            break
        el = max(over, key=lambda k: size[k])
    return el


def _refuse_expansion(path: Path, el: Any, size: dict[Any, tuple[int, int, int]]) -> None:
    n, v, d = size[el]
    if d > MAX_DEPTH:
        what = f"elements nested {d:,} deep, more than the {MAX_DEPTH} levels allowed"
    elif n > MAX_ELEMENTS:
        what = f"{n:,} elements, more than the {MAX_ELEMENTS:,} allowed"
    else:
        what = f"{v:,} outline points, more than the {MAX_SOURCE_POINTS:,} allowed"
    raise ResourceError(f"{path}, {_name(el)}: this draws {what} (every <use> counted as a "
                        "copy of what it refers to); nothing was drawn. Simplify the drawing "
                        "(unite shapes, replace nested <use> by one path) or split it")
