"""Bead widths of sliced G-code: the slicer's own, or derived from the filament fed.

The width rules (comments first, else the ``stadium`` or ``rectangle``
cross-section inverted from E, outliers capped) and the bead union of one
layer; :mod:`printability.sources.gcode` describes them and builds the layer
targets from them.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from gcode import GCodeFile
from printability.errors import InputError

__all__ = ["BEAD_MODELS", "bead_widths", "beads_union", "chains", "resolve_bead_model",
           "segment_widths"]

BEAD_MODELS = ("auto", "stadium", "rectangle")


def resolve_bead_model(g: GCodeFile, bead_model: str) -> str:
    """``stadium`` or ``rectangle``; ``auto`` is the rectangle for Cura files (Cura plans
    its lines as rectangles), the stadium for every other slicer."""
    if bead_model not in BEAD_MODELS:
        raise InputError(f"unknown bead model {bead_model!r}; expected one of {BEAD_MODELS}")
    if bead_model != "auto":
        return bead_model
    return "rectangle" if g.slicer == "Cura" else "stadium"


def bead_widths(
    e: np.ndarray,
    length: np.ndarray,
    height: np.ndarray,
    *,
    filament_diameter: float,
    model: str,
) -> np.ndarray:
    """Bead width (mm) from filament fed ``e`` (mm) over ``length`` (mm) at layer ``height`` (mm).

    ``model`` is ``"stadium"`` or ``"rectangle"`` (see the module docs).
    NaN where ``length`` or ``height`` is not positive.
    """
    area_f = math.pi * filament_diameter**2 / 4.0
    with np.errstate(divide="ignore", invalid="ignore"):
        w = area_f * np.asarray(e, float) / (np.asarray(length, float) * np.asarray(height, float))
    if model == "stadium":
        w = w + np.asarray(height, float) * (1.0 - math.pi / 4.0)
    elif model != "rectangle":
        raise InputError(f"unknown bead model {model!r}; expected stadium or rectangle")
    return np.where((np.asarray(length) > 0) & (np.asarray(height) > 0), w, np.nan)


def chains(seg: np.ndarray, width: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Chain id per segment: a new chain where the path breaks or the width changes."""
    if len(seg) == 0:
        return np.zeros(0, np.int64)
    brk = np.ones(len(seg), bool)
    brk[1:] = (
        (np.abs(seg["x0"][1:] - seg["x1"][:-1]) > tol)
        | (np.abs(seg["y0"][1:] - seg["y1"][:-1]) > tol)
        | (np.abs(width[1:] - width[:-1]) > tol)
    )
    return np.cumsum(brk) - 1


def beads_union(seg: np.ndarray, width: np.ndarray, quad_segs: int):
    """Union of round-capped beads along ``seg`` (one chain per polyline)."""
    chain = chains(seg, width)
    n_chain = int(chain[-1]) + 1
    first = np.searchsorted(chain, np.arange(n_chain), side="left")
    # polyline vertices: each chain's first start point, then every end point
    xy_end = np.column_stack([seg["x1"], seg["y1"]])
    xy_first = np.column_stack([seg["x0"][first], seg["y0"][first]])
    coords = np.concatenate([xy_first, xy_end])
    ids = np.concatenate([np.arange(n_chain), chain])
    order = np.argsort(
        np.concatenate([first * 2, np.arange(len(seg)) * 2 + 1]), kind="stable"
    )
    lines = shapely.linestrings(coords[order], indices=ids[order])
    beads = shapely.buffer(
        lines, width[first] / 2.0, quad_segs=quad_segs, cap_style="round", join_style="round"
    )
    return shapely.union_all(beads)


def segment_widths(
    g: GCodeFile,
    seg: np.ndarray,
    mv: np.ndarray,
    *,
    filament_diameter: float,
    model: str,
    use_width_comments: bool = True,
    max_width_factor: float = 3.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bead width of every chord, as the layer targets are built from: one rule for
    :func:`layer_regions` and the post-processor, so a round nozzle laying these widths
    fits the targets by construction.

    Parameters
    ----------
    g
        The parsed file.
    seg, mv
        Chords (:meth:`GCodeFile.segments`) and the row of ``g.moves`` of each.
    model
        One of :data:`BEAD_MODELS` (see :func:`resolve_bead_model`).

    Returns
    -------
    (width, derived, clipped)
        Width, mm (NaN where unknown); True where it was derived from E (no
        ``;WIDTH:`` comment, or comments ignored); True where it was clipped.

    Notes
    -----
    A derived width is the bead whose cross-section carries the move's
    filament over the move's whole length (so an arc's chords share one
    width), rounded to 1 µm (far below E's own rounding noise, and runs of
    moves then share one polyline). Outliers are capped at
    ``max_width_factor`` × the file's median derived width (per-layer
    medians mislead on layers of thin gap fill); on a layer with derived
    widths the cap applies to every width. Zero-length chords take their
    move's width and count for neither the median nor the layer rule.
    """
    model = resolve_bead_model(g, model)
    m = g.moves
    length = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"])
    has_len = length > 0
    layer = m["layer"][mv]
    heights = g.layers["height"][np.maximum(layer, 0)]
    width = (m["width"][mv].astype(float) if use_width_comments
             else np.full(len(mv), np.nan))
    derived = ~np.isfinite(width)
    if derived.any():
        uniq, inv = np.unique(mv, return_inverse=True)
        l_move = np.bincount(inv, weights=length, minlength=len(uniq))
        width[derived] = np.round(
            bead_widths(m["e"][mv[derived]], l_move[inv[derived]], heights[derived],
                        filament_diameter=filament_diameter, model=model),
            3,
        )
    dw = width[derived & has_len]
    dw = dw[np.isfinite(dw) & (dw > 0)]
    cap = max_width_factor * float(np.median(dw)) if len(dw) else math.inf
    n_layers = max(len(g.layers), int(layer.max()) + 1 if len(layer) else 0)
    with_derived = np.zeros(n_layers + 1, dtype=bool)
    with_derived[layer[derived & has_len]] = True
    with np.errstate(invalid="ignore"):
        clipped = with_derived[layer] & np.isfinite(width) & (width > cap)
    width = np.where(clipped, cap, width)
    return width, derived, clipped
