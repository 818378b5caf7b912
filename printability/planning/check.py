"""Check what a G-code file deposits against each layer's target (MMC verification).

Independent of the planner: the nozzle outline is *placed* at sampled
positions and angles along every extruding move (no swept-hull formula, no
support functions), and each placed outline's vertices are measured against
the target with shapely's distance. The rotary coordinate of every move is
read from the file's own words (the axis letter, forward-filled), so this
checks what a printer would do.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.model.nozzle import Nozzle

__all__ = ["LayerDeposition", "check_deposition", "extrusion_chords"]


@dataclass(frozen=True)
class LayerDeposition:
    """What the moves of one layer deposit, against its target.

    Attributes
    ----------
    layer
        Layer index in the checked file.
    moves
        Extruding chords checked.
    samples
        Nozzle placements measured.
    max_outside
        Largest distance of a placed outline's vertex outside the target, mm
        (0 when everything is inside).
    deposited
        Union of the placed outlines (shapely), when asked for.
    """

    layer: int
    moves: int
    samples: int
    max_outside: float
    deposited: BaseGeometry | None = None


def extrusion_chords(g, *, letter: str = "C", part_only: bool = True) -> np.ndarray:
    """Extruding chords of a parsed file with the rotary coordinate at both ends.

    Returns a structured array with fields ``layer, x0, y0, x1, y1, a0, a1``
    (angles in degrees; 0 before the first rotary word). Arcs are linearised.
    """
    from gcode import NON_PART_CATEGORIES

    m = g.moves
    code = ord(letter.upper())
    w = g.words
    cw = w[(w["letter"] == code) & np.isfinite(w["value"])]
    # rotary coordinate after each line (forward-filled), then per move
    after = np.full(len(g.lines), np.nan)
    after[cw["line"]] = cw["value"]
    idx = np.where(np.isfinite(after), np.arange(len(after)), -1)
    np.maximum.accumulate(idx, out=idx)
    c_after = np.where(idx >= 0, after[np.maximum(idx, 0)], 0.0)
    c1 = c_after[m["line"]]
    c0 = np.where(m["line"] > 0, c_after[np.maximum(m["line"] - 1, 0)], 0.0)
    keep = m["is_extrusion"] & (m["layer"] >= 0) & ~m["wipe"]
    if part_only:
        keep &= ~g.moves_in(NON_PART_CATEGORIES)
    sel = np.flatnonzero(keep)
    seg = g.segments(moves=m[sel])
    mv = sel[seg["move"]]
    # angle interpolated along the move: chord k of n gets [k/n, (k+1)/n]
    counts = np.bincount(seg["move"], minlength=len(sel))
    first = np.cumsum(counts) - counts
    k = np.arange(len(seg)) - first[seg["move"]]
    n = counts[seg["move"]]
    a0m, a1m = c0[mv], c1[mv]
    out = np.empty(len(seg), dtype=[("layer", "i4"), ("x0", "f8"), ("y0", "f8"), ("x1", "f8"),
                                    ("y1", "f8"), ("a0", "f8"), ("a1", "f8")])
    out["layer"] = m["layer"][mv]
    for f in ("x0", "y0", "x1", "y1"):
        out[f] = seg[f]
    out["a0"] = a0m + (a1m - a0m) * k / n
    out["a1"] = a0m + (a1m - a0m) * (k + 1) / n
    return out


def check_deposition(
    chords: np.ndarray,
    targets: Sequence[BaseGeometry | None],
    nozzle: Nozzle,
    *,
    layers: Sequence[int] | None = None,
    step: float = 0.05,
    angle_step: float = 1.0,
    quad_segs: int = 16,
    keep_union: bool = False,
) -> list[LayerDeposition]:
    """Measure how far the nozzle goes outside each layer's target while extruding.

    Parameters
    ----------
    chords
        From :func:`extrusion_chords`.
    targets
        Target G per layer index (None: layer skipped).
    nozzle
        The nozzle whose outline is placed (inner polygon: vertices on the curve).
    layers
        Layer indices to check (default all with a target).
    step, angle_step
        Sampling along each chord: at most ``step`` mm and ``angle_step``
        degrees between placements (both ends included).
    keep_union
        Also return the union of the placed outlines (for coverage figures).
    """
    base = nozzle.outline(0.0, quad_segs=quad_segs, mode="inner")
    verts = np.concatenate([np.asarray(p.exterior.coords)[:-1]
                            for p in shapely.get_parts(base)])
    out = []
    todo = range(len(targets)) if layers is None else layers
    for li in todo:
        tgt = targets[li]
        if tgt is None:
            continue
        c = chords[chords["layer"] == li]
        if len(c) == 0:
            continue
        length = np.hypot(c["x1"] - c["x0"], c["y1"] - c["y0"])
        turn = np.abs(c["a1"] - c["a0"])
        ns = np.maximum(np.ceil(length / step), np.ceil(turn / angle_step)).astype(int) + 1
        rep = np.repeat(np.arange(len(c)), ns)
        first = np.cumsum(ns) - ns
        t = (np.arange(rep.size) - first[rep]) / np.maximum(ns[rep] - 1, 1)
        shapely.prepare(tgt)
        worst = 0.0
        unions = []
        # in batches, so that memory stays bounded (a point object per outline vertex)
        batch = max(1, 200_000 // len(verts))
        for lo in range(0, rep.size, batch):
            r, tt = rep[lo:lo + batch], t[lo:lo + batch]
            px = c["x0"][r] + tt * (c["x1"] - c["x0"])[r]
            py = c["y0"][r] + tt * (c["y1"] - c["y0"])[r]
            ang = np.deg2rad(c["a0"][r] + tt * (c["a1"] - c["a0"])[r])
            cs, sn = np.cos(ang)[:, None], np.sin(ang)[:, None]
            vx = px[:, None] + cs * verts[None, :, 0] - sn * verts[None, :, 1]
            vy = py[:, None] + sn * verts[None, :, 0] + cs * verts[None, :, 1]
            pts = shapely.points(vx.ravel(), vy.ravel())
            inside = shapely.covers(tgt, pts)
            if not inside.all():
                worst = max(worst, float(shapely.distance(tgt, pts[~inside]).max()))
            if keep_union:
                ring = np.stack([vx, vy], axis=-1)
                ring = np.concatenate([ring, ring[:, :1]], axis=1)
                unions.append(shapely.union_all(shapely.polygons(ring)))
        union = shapely.union_all(unions) if keep_union else None
        out.append(LayerDeposition(int(li), len(c), int(rep.size),
                                   worst if math.isfinite(worst) else math.inf, union))
    return out
