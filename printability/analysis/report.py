"""The visual report of an analysis: a self-contained HTML page with figures, and the
as-built geometry as GeoJSON, SVG and (for several layers) a mesh.

For each nozzle the page shows, like the seed paper's Fig. 3, the target G,
the as-built layer S and the lost parts G \\ S in colour for the layer that
loses most; the motion restriction P in its parameter space (on a rotary
machine: how many sampled angles fit at each position, and a few angle
slices); the components of P in colour; and, for several layers, the lost
area per layer. Figures are PNG files beside the page and embedded in it, so
the page can be mailed alone.

Colours follow the numbers: red (lost) only where an engine's S says material is lost, on
a layer whose lost area is not 0; the raster engine's S is its certified *inner* bound, so
what it leaves out is orange (not proven printed), with the estimate and the bounds in the
legend. Totals use one unit (:func:`printability.analysis.ranking.totals`): volumes (mm³) for
several layers with heights, areas (mm²) otherwise.

Needs matplotlib (the ``report`` extra).
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import mapping
from shapely.geometry.base import BaseGeometry

from printability import __version__
from printability.analysis import Analysis, LayerOutcome, NozzleAnalysis
from printability.errors import InputError
from printability.model.geometry import Raster, polygons_of

__all__ = ["COLORS", "draw_geometry", "draw_layer", "is_inner_bound", "lost_pieces", "write_report"]

COLORS = {"target": "#d9d9d9", "as_built": "#4c9be8", "lost": "#e8514c", "p": "#2ca25f",
          "uncertain": "#f0a030"}
"""The figures' colours (the demo's report uses the same)."""


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError(
            "the report needs matplotlib: pip install 'printability[report]'"
        ) from None
    return plt


def draw_geometry(ax, geom: BaseGeometry | None, color: str, *, alpha: float = 1.0, label=None,
                  zorder: float = 1.0, edge: str = "none") -> None:
    """Fill a shapely geometry on a matplotlib axis, its holes left empty.

    Parameters
    ----------
    ax
        The matplotlib axis.
    geom
        Polygons (anything :func:`printability.model.geometry.polygons_of` reads); None or
        empty draws nothing.
    color, alpha, zorder
        The fill.
    label
        Legend entry (given to the first polygon only).
    edge
        Outline colour (``"none"``: no outline).

    Notes
    -----
    matplotlib fills a path by the non-zero winding rule, so a hole wound like its
    exterior (as rasters, drawings and GeoJSON may give them) would be filled: each
    polygon is oriented first, exterior counter-clockwise and holes clockwise.
    """
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath
    from shapely.geometry.polygon import orient

    if geom is None or geom.is_empty:
        return
    for k, poly in enumerate(polygons_of(geom)):
        poly = orient(poly, 1.0)
        verts, codes = [], []
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            verts.append(xy)
            codes += [MplPath.MOVETO] + [MplPath.LINETO] * (len(xy) - 2) + [MplPath.CLOSEPOLY]
        path = MplPath(np.concatenate(verts), codes)
        ax.add_patch(PathPatch(path, facecolor=color, edgecolor=edge, alpha=alpha, zorder=zorder,
                               linewidth=1.2, label=label if k == 0 else None))


def lost_pieces(target: BaseGeometry, as_built: BaseGeometry, *,
                resolution: float) -> tuple[BaseGeometry, BaseGeometry]:
    """G \\ S, and the part of it worth outlining on a page.

    S is certified from inside, so G \\ S holds, besides the real losses (a fin,
    a corner cusp), a band a few micrometres thick along the whole boundary.
    Filled, that band is invisible, as it should be; outlined, it would paint
    the whole part as lost. Returns ``(lost, salient)``: ``salient`` is ``lost``
    opened by a tenth of the grid spacing (at least 1/2000 of the part's size),
    which removes the band and keeps every loss that shows at page scale.
    """
    lost = target.difference(as_built)
    if lost.is_empty:
        return lost, lost
    minx, miny, maxx, maxy = target.bounds
    t = max(0.1 * resolution, 5e-4 * max(maxx - minx, maxy - miny))
    salient = lost.buffer(-t, quad_segs=4).buffer(t, quad_segs=4).intersection(lost)
    return lost, salient


def _show_raster(ax, raster: Raster, cmap: str, *, mask_zero: bool = True, **kw) -> Any:
    g = raster.grid
    data = np.ma.masked_equal(raster.data, 0) if mask_zero else raster.data
    x0, y0, x1, y1 = g.bounds
    # images draw above the grey target (patches default to zorder 1)
    return ax.imshow(data, origin="lower", extent=(x0, x1, y0, y1), cmap=cmap,
                     interpolation="nearest", zorder=2, **kw)


def _frame(ax, geom: BaseGeometry) -> None:
    minx, miny, maxx, maxy = geom.bounds
    pad = 0.03 * max(maxx - minx, maxy - miny)
    ax.set_xlim(minx - pad, maxx + pad)
    ax.set_ylim(miny - pad, maxy + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def _png(plt, fig) -> bytes:
    """The figure as PNG bytes; the figure is closed."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _worst_layer(n: NozzleAnalysis) -> LayerOutcome:
    return max(n.layers, key=lambda o: (o.lost_area, -o.index))


def is_inner_bound(r) -> bool:
    """Whether a result's S geometry is an inner bound, not the S its figures measure."""
    return r.engine == "raster" or (
        r.as_built is not None
        and abs(r.as_built.area - r.as_built_area) > 1e-6 * max(1.0, r.target_area))


def draw_layer(ax, o: LayerOutcome, target: BaseGeometry, *, numbers: bool = True) -> None:
    """Draw one nozzle's result on one layer: S, and what it leaves out, in the colours
    that match the numbers.

    Parameters
    ----------
    ax
        The matplotlib axis.
    o
        The layer's outcome (with its engine result, or None when the nozzle fits nowhere).
    target
        The layer G.
    numbers
        Put the areas in the legend labels (a figure with one panel); without, the labels
        are the same on every panel, for one legend shared by several.

    Notes
    -----
    Red (lost) is drawn only on a layer whose lost area is not 0, and only where S leaves
    G out by more than the micrometre band of a certified S. An S that is an inner bound
    (the raster engine's S_inner) leaves out what is merely not proven printed: orange, with
    the estimate and the certified bounds in the label.
    """
    from matplotlib.colors import ListedColormap

    r = o.result
    lo, hi = o.lost_area_bounds

    def lost_label() -> str:
        return f"lost (G \\ S): {o.lost_area:.3g} mm²" if numbers else "lost (G \\ S)"

    def uncertain_label(area: float | None) -> str:
        if not numbers:
            return "not proven printed (G \\ S_inner)"
        what = "G \\ S_inner" if area is None else f"G \\ S_inner, {area:.3g} mm²"
        return (f"not proven printed ({what}): the estimate loses {o.lost_area:.3g} mm², "
                f"certified [{lo:.3g}, {hi:.3g}]")

    if r is not None and r.as_built is not None:
        draw_geometry(ax, r.as_built, COLORS["as_built"], label="as built (S)")
        lost, salient = lost_pieces(target, r.as_built, resolution=r.resolution)
        if is_inner_bound(r):
            # what an inner bound leaves out is not proven printed, and the estimate of the
            # loss is not a region the result keeps
            label = uncertain_label(lost.area)
            draw_geometry(ax, lost, COLORS["uncertain"], label=label, zorder=3)
            if lost.is_empty:
                ax.plot([], [], color=COLORS["uncertain"], lw=8, label=label)
        elif o.lost_area > 0:
            # an edge keeps thin lost slivers visible at page scale; the micrometre band of
            # a certified S along the whole boundary is neither filled nor outlined
            draw_geometry(ax, salient, COLORS["lost"], edge=COLORS["lost"], label=lost_label(),
                  zorder=3)
            if salient.is_empty:
                ax.plot([], [], color=COLORS["lost"], lw=8, label=lost_label())
    elif r is not None and r.as_built_raster is not None:
        # S known only as pixels (the raster engine's inner bound): paint them over the
        # target, which shows through where S_inner does not reach
        draw_geometry(ax, target, COLORS["uncertain"], label=uncertain_label(None), zorder=0)
        _show_raster(ax, Raster(r.as_built_raster.grid, r.as_built_raster.data.astype(np.uint8)),
                     ListedColormap([COLORS["as_built"]]))
        ax.plot([], [], color=COLORS["as_built"], lw=8, label="as built (S_inner, pixels)")
    else:  # the nozzle fits nowhere in the layer: all of it is lost
        draw_geometry(ax, target, COLORS["lost"], label=lost_label(), zorder=0)


def _fig_layer(plt, o: LayerOutcome, target: BaseGeometry, title: str) -> bytes:
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    draw_layer(ax, o, target)
    _frame(ax, target)
    ax.set_title(title)
    # below the axes: inside, the legend's swatches would stand on the drawing (a red
    # swatch in the middle of a part that loses only its corners)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=8, frameon=False)
    return _png(plt, fig)


def _fig_motion(plt, o: LayerOutcome, target: BaseGeometry, title: str) -> bytes | None:
    r = o.result
    if r is None:
        return None
    m = r.motion
    angles = np.asarray(m.angles)
    n_slices = min(3, len(angles)) if len(angles) > 1 else 0
    fig, axes = plt.subplots(1, 1 + n_slices, figsize=(5.5 * (1 + n_slices), 5), squeeze=False)
    ax = axes[0, 0]
    draw_geometry(ax, target, COLORS["target"], zorder=0)
    if m.count is not None:
        im = _show_raster(ax, m.count, "viridis")
        fig.colorbar(im, ax=ax, shrink=0.8, label="angles that fit")
        ax.set_title(f"P: where how many of {len(angles)} angles fit")
    elif m.regions is not None:
        if len(m.regions) == 1:
            draw_geometry(ax, m.regions[0], COLORS["p"])
            ax.set_title("P: positions of the nozzle origin")
        else:
            # count of angles per position, drawn as overlapping translucent layers
            alpha = max(0.02, min(0.5, 3.0 / len(m.regions)))
            for reg in m.regions:
                draw_geometry(ax, reg, COLORS["p"], alpha=alpha)
            ax.set_title(f"P over {len(angles)} angles (darker: more angles fit)")
    _frame(ax, target)
    for j in range(n_slices):
        k = round(j * (len(angles) - 1) / max(1, n_slices - 1)) if n_slices > 1 else 0
        ax = axes[0, 1 + j]
        draw_geometry(ax, target, COLORS["target"], zorder=0)
        if m.regions is not None:
            draw_geometry(ax, m.regions[k], COLORS["p"])
        else:
            mask = _mask_at(m, k)
            if mask is not None:
                from matplotlib.colors import ListedColormap

                _show_raster(ax, Raster(mask.grid, mask.data.astype(np.uint8)),
                             ListedColormap([COLORS["p"]]))
        _frame(ax, target)
        ax.set_title(f"P at φ = {angles[k]:.1f}°")
    fig.suptitle(title)
    return _png(plt, fig)


def _mask_at(motion, k: int) -> Raster | None:
    getter = getattr(motion, "mask", None)
    if callable(getter):
        return getter(k)
    if motion.masks is not None and motion.masks.data.ndim == 3:
        return Raster(motion.masks.grid, motion.masks.data[k])
    return None


def _fig_components(plt, o: LayerOutcome, target: BaseGeometry, title: str) -> bytes | None:
    r = o.result
    if r is None or not r.components.geometries:
        return None
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    draw_geometry(ax, target, COLORS["target"], zorder=0)
    cmap = plt.get_cmap("tab20")
    for i, geom in enumerate(r.components.geometries):
        draw_geometry(ax, geom, cmap(i % 20))
    _frame(ax, target)
    ax.set_title(f"{title}: {r.components.count} component(s) of P")
    return _png(plt, fig)


def _fig_overview(plt, analysis: Analysis) -> tuple[bytes, float]:
    """Every nozzle on one layer, side by side: the layer where some nozzle loses most.

    Returns the PNG and that layer's z.
    """
    from matplotlib.patches import Patch

    nozzles = analysis.nozzles
    i = max(range(len(analysis.layers)),
            key=lambda k: (max(n.layers[k].lost_area for n in nozzles), -k))
    target = analysis.layers[i].region
    cols = min(len(nozzles), 4)
    rows = -(-len(nozzles) // cols)
    x0, y0, x1, y1 = target.bounds
    aspect = min(2.0, max(0.25, (y1 - y0) / max(x1 - x0, 1e-9)))  # panels shaped like the part
    fig, axes = plt.subplots(rows, cols, squeeze=False,
                             figsize=(4.2 * cols, (3.4 * aspect + 1.1) * rows + 0.5))
    used = {"target", "as_built"}
    for ax in axes.flat[len(nozzles):]:
        ax.set_visible(False)
    for ax, n in zip(axes.flat, nozzles, strict=False):
        o = n.layers[i]
        draw_geometry(ax, target, COLORS["target"], zorder=0)
        draw_layer(ax, o, target, numbers=False)
        if o.result is not None and is_inner_bound(o.result):
            used.add("uncertain")
        elif o.lost_area > 0:
            used.add("lost")
        lo, hi = o.lost_area_bounds
        ax.set_title(f"#{n.rank} {n.nozzle.spec}\nlost {o.lost_area:.3g} mm² "
                     f"[{lo:.3g}, {hi:.3g}]", fontsize=9)
        _frame(ax, target)
        ax.tick_params(labelsize=7)
        ax.xaxis.label.set_size(8)
        ax.yaxis.label.set_size(8)
    names = {"target": "target G", "as_built": "as built (S)", "lost": "lost (G \\ S)",
             "uncertain": "not proven printed (G \\ S_inner)"}
    fig.legend(handles=[Patch(color=COLORS[k], label=v) for k, v in names.items() if k in used],
               loc="lower center", ncol=4, fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    fig.suptitle(f"All nozzles on the layer z = {analysis.layers[i].z:g} mm", fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.97), h_pad=0.5, w_pad=0.5)
    return _png(plt, fig), analysis.layers[i].z


def _fig_per_layer(plt, analysis: Analysis) -> bytes:
    fig, ax = plt.subplots(figsize=(7, 3))
    for n in analysis.nozzles:
        ax.plot([o.z for o in n.layers], [o.lost_area for o in n.layers], marker=".",
                label=n.nozzle.spec)
    ax.set_xlabel("layer z (mm)")
    ax.set_ylabel("lost area (mm²)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Lost area per layer")
    return _png(plt, fig)


def _geojson(n: NozzleAnalysis, analysis: Analysis) -> dict[str, Any]:
    """The as-built layers as GeoJSON features, each saying what its geometry is.

    A raster result's geometry is S_inner, the certified inner bound, while its
    ``as_built_area`` and ``lost_area`` are the engine's estimates: ``geometry_is`` and
    ``geometry_area`` tell them apart.
    """
    feats = []
    for o, layer in zip(n.layers, analysis.layers, strict=True):
        geom = None
        what = "S"
        if o.result is not None and o.result.as_built is not None:
            geom = o.result.as_built
            if is_inner_bound(o.result):
                what = "S_inner (certified inner bound: printed for sure)"
        elif o.result is None:
            geom = shapely.MultiPolygon()
        if geom is None:
            continue
        feats.append({"type": "Feature", "geometry": mapping(geom),
                      "properties": {"z": layer.z, "height": layer.height,
                                     "geometry_is": what, "geometry_area": float(geom.area),
                                     "as_built_area": o.as_built_area,
                                     "lost_area": o.lost_area,
                                     "lost_area_bounds": list(o.lost_area_bounds),
                                     "nozzle": n.nozzle.spec}})
    return {"type": "FeatureCollection", "features": feats}


def _svg(geom: BaseGeometry, target: BaseGeometry) -> str:
    minx, miny, maxx, maxy = target.bounds
    w, h = maxx - minx, maxy - miny
    paths = []
    for poly in polygons_of(geom):
        d = ""
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            # SVG's y axis points down: flip so the drawing reads like the plots
            pts = " L ".join(f"{x - minx:.4f},{maxy - y:.4f}" for x, y in xy[:-1])
            d += f"M {pts} Z "
        paths.append(f'<path d="{d.strip()}" fill-rule="evenodd"/>')
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.4f}mm" height="{h:.4f}mm" '
            f'viewBox="0 0 {w:.4f} {h:.4f}"><g fill="#4c9be8">{"".join(paths)}</g></svg>\n')


_MESH_EPSILON = 1e-4
"""The exported solid is S pulled in by this much, its vertices at least this far apart, mm."""


def _mesh(n: NozzleAnalysis, analysis: Analysis) -> bytes | None:
    """The as-built layers as one closed solid, a binary STL (None when nothing is built).

    Each layer's S is extruded over its height and the prisms are united (manifold3d), so
    the faces where two layers touch disappear: a watertight, 2-manifold mesh a slicer or
    a CAD program reads as closed bodies, not a stack of prisms sharing faces. S is pulled
    in by :data:`_MESH_EPSILON` (0.1 µm) so that parts touching at a point or an edge stay
    apart.
    """
    import trimesh
    from manifold3d import CrossSection, FillRule, JoinType, Manifold, OpType

    solids = []
    for o, layer in zip(n.layers, analysis.layers, strict=True):
        if o.result is None or o.result.as_built is None or layer.height <= 0:
            continue
        contours = [np.asarray(ring.coords, dtype=float)[:-1]
                    for poly in polygons_of(o.result.as_built)
                    for ring in (poly.exterior, *poly.interiors)]
        # Pulled in by 0.1 µm: parts of S that touch at a corner or along an edge (and
        # layers that touch only along an edge) would share an edge among four triangles,
        # which an STL cannot tell from a pinched body; vertices closer than 0.1 µm would
        # fall together in its float32 coordinates.
        section = (CrossSection(contours, FillRule.EvenOdd)
                   .offset(-_MESH_EPSILON, JoinType.Miter).simplify(_MESH_EPSILON)
                   if contours else None)
        if section is None or section.is_empty():
            continue
        # rounded, so that a layer's bottom is exactly the top of the one below (the union
        # would keep a sliver between 0.4 and 0.6 - 0.2 = 0.39999999999999997)
        top, bottom = round(layer.z, 6), round(layer.z - layer.height, 6)
        solids.append(Manifold.extrude(section, top - bottom).translate((0.0, 0.0, bottom)))
    if not solids:
        return None
    mesh = Manifold.batch_boolean(solids, OpType.Add).to_mesh64()
    # The STL stores float32: round first, merge the vertices that meet (a reader does the
    # same) and drop the triangles that collapse, so the file itself is closed.
    verts = np.asarray(mesh.vert_properties)[:, :3].astype(np.float32).astype(np.float64)
    solid = trimesh.Trimesh(verts, np.asarray(mesh.tri_verts, dtype=np.int64), process=False)
    solid.merge_vertices()
    f = solid.faces
    solid.update_faces((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    solid.remove_unreferenced_vertices()
    return solid.export(file_type="stl")


def _img(name: str, data: bytes, alt: str) -> str:
    b64 = base64.b64encode(data).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{b64}" alt="{html.escape(alt)}">'
            f'<figcaption><a href="{html.escape(name)}">{html.escape(name)}</a></figcaption>'
            "</figure>")


def _nozzle_report(plt, n: NozzleAnalysis, analysis: Analysis, out: Path,
                   volume: bool) -> tuple[str, str, bool]:
    """Write one nozzle's figures (of the layer it loses most on) and as-built geometry;
    return its row of the ranking table, its section of the page, and whether some layer's S
    is an inner bound."""
    from printability.analysis.ranking import rank_label, totals
    from printability.app.cli.common import write_atomic

    t = totals(n.layers, volume=volume)
    area = totals(n.layers, volume=False)
    lo, hi = t.lost_bounds
    label = rank_label(n.rank_range) if n.rank_range != (0, 0) else str(n.rank)
    row = (f"<tr><td>{html.escape(label)}</td><td><code>{html.escape(n.nozzle.spec)}</code></td>"
           f"<td>{t.lost:.4g}</td><td>{100 * t.lost_fraction:.2f}</td>"
           f"<td>[{lo:.4g}, {hi:.4g}]</td>"
           + (f"<td>{area.lost:.4g}</td><td>[{area.lost_bounds[0]:.4g}, "
              f"{area.lost_bounds[1]:.4g}]</td>" if volume else "")
           + f"<td>{n.components}</td></tr>")
    slug = f"nozzle{n.rank}"
    worst = _worst_layer(n)
    target = analysis.layers[worst.index].region
    title = f"{n.nozzle.spec} — layer z = {worst.z:g} mm"
    figs = []
    for tag, maker in (("layer", _fig_layer), ("motion", _fig_motion),
                       ("components", _fig_components)):
        data = maker(plt, worst, target, title)
        if data is not None:
            name = f"{slug}_{tag}.png"
            write_atomic(out / name, data)
            figs.append(_img(name, data, f"{tag} figure for {n.nozzle.spec}"))
    links = [f"{slug}_as_built.geojson"]
    write_atomic(out / links[-1], json.dumps(_geojson(n, analysis)))
    if worst.result is not None and worst.result.as_built is not None:
        links.append(f"{slug}_as_built.svg")
        write_atomic(out / links[-1], _svg(worst.result.as_built, target))
    mesh = _mesh(n, analysis) if analysis.multi_layer else None
    if mesh is not None:
        links.append(f"{slug}_as_built.stl")
        write_atomic(out / links[-1], mesh)
    inner = any(o.result is not None and is_inner_bound(o.result) for o in n.layers)
    notes = "".join(f"<li>{html.escape(t)}</li>" for t in
                    (worst.result.notes if worst.result is not None else (worst.note,)) if t)
    w_lo, w_hi = worst.lost_area_bounds
    section = (
        f"<section><h2>#{n.rank}: <code>{html.escape(n.nozzle.spec)}</code></h2>"
        f"<p>Lost {t.lost:.4g} {t.unit} of {t.target:.4g} {t.unit} "
        f"({100 * t.lost_fraction:.2f} %), certified bounds [{lo:.4g}, {hi:.4g}] {t.unit}"
        + (" (the engine's estimate within them)" if inner else "") + ". "
        f"Figures show the layer that loses most: z = {worst.z:g} mm, lost "
        f"{worst.lost_area:.4g} mm², bounds [{w_lo:.4g}, {w_hi:.4g}] mm².</p>"
        f"{''.join(figs)}<ul>{notes}</ul><p>Geometry"
        + (" (the certified inner bound S_inner: printed for sure; the figures above are "
           "the estimate)" if inner else "") + ": "
        + ", ".join(f'<a href="{html.escape(x)}">{html.escape(x)}</a>' for x in links)
        + "</p></section>")
    return row, section, inner


def write_report(analysis: Analysis, out_dir: str | Path) -> Path:
    """Write ``index.html``, PNG figures and the as-built geometry into ``out_dir``.

    Every file is written atomically. Returns the path of ``index.html``.
    """
    from printability.analysis.ranking import uses_volume
    from printability.app.cli.common import write_atomic

    plt = _pyplot()
    out = Path(out_dir)
    volume = uses_volume([lay.height for lay in analysis.layers])
    parts = [_nozzle_report(plt, n, analysis, out, volume) for n in analysis.nozzles]
    rows, sections = [p[0] for p in parts], [p[1] for p in parts]
    any_inner = any(p[2] for p in parts)
    overview = ""
    if len(analysis.nozzles) > 1:
        data, z = _fig_overview(plt, analysis)
        write_atomic(out / "overview.png", data)
        overview = _img("overview.png", data, f"every nozzle on the layer z = {z:g} mm")
    per_layer = ""
    if analysis.multi_layer:
        data = _fig_per_layer(plt, analysis)
        write_atomic(out / "lost_per_layer.png", data)
        per_layer = _img("lost_per_layer.png", data, "lost area per layer")
    unit = "mm³" if volume else "mm²"
    heads = [f"lost {unit}", "lost %", f"bounds {unit}"]
    if volume:
        heads += ["lost area mm² (Σ layers)", "bounds mm² (Σ layers)"]
    head = "".join(f"<th>{html.escape(h)}</th>" for h in ("rank", "nozzle", *heads,
                                                           "components"))
    what = ("Lost: the volume of G \\ S, each layer's lost area times its height, summed."
            if volume else "Lost: the area of G \\ S"
            + (", summed over the layers." if analysis.multi_layer else "."))
    ties = ""
    if analysis.ties:
        ties = (" Ranks A–B: tied within the certified bounds (the intervals overlap, so the "
                "order of the estimates is not certain): "
                + "; ".join(f"{a} and {b}" for a, b in analysis.ties) + ".")
    refined = ""
    if analysis.refinement is not None:
        from printability.app.cli.analyze import ranking_notes

        refined = "<ul>" + "".join(f"<li>{html.escape(line)}</li>" for line in
                                   ranking_notes(analysis, suggest=False)
                                   if not line.startswith("tied")) + "</ul>"
    uncertain_key = (f'<span style="background:{COLORS["uncertain"]}"></span>not proven '
                     "printed (outside a raster engine's certified inner S)" if any_inner else "")
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>printability report — {html.escape(analysis.input)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; color: #222; }}
table {{ border-collapse: collapse; }} td, th {{ border: 1px solid #ccc; padding: 4px 8px; }}
figure {{ display: inline-block; margin: 0.5em; }} img {{ max-width: 100%; }}
.key span {{ display: inline-block; width: 1em; height: 1em; margin: 0 0.3em 0 1em; }}
</style></head><body>
<h1>printability report</h1>
<p>Input <code>{html.escape(analysis.input)}</code>,
machine <code>{html.escape(analysis.machine.spec)}</code>,
engine {html.escape(analysis.engine)}, resolution {analysis.settings.resolution:g} mm,
{len(analysis.layers)} layer(s), computed in {analysis.elapsed:.2f} s
by printability {__version__}.</p>
<p class="key"><span style="background:{COLORS['as_built']}"></span>as built (S)
<span style="background:{COLORS['lost']}"></span>lost (G \\ S)
{uncertain_key}
<span style="background:{COLORS['p']}"></span>motion restriction P</p>
<table><tr>{head}</tr>{''.join(rows)}</table>
<p>{html.escape(what)} Bounds: the certified interval of that figure.{html.escape(ties)}</p>
{refined}
{overview}
{per_layer}
{''.join(sections)}
</body></html>
"""
    index = out / "index.html"
    write_atomic(index, page)
    return index
