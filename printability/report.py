"""The visual report of an analysis: a self-contained HTML page with figures, and the
as-built geometry as GeoJSON, SVG and (for several layers) a mesh.

For each nozzle the page shows, like the seed paper's Fig. 3, the target G,
the as-built layer S and the lost parts G \\ S in colour for the layer that
loses most; the motion restriction P in its parameter space (on a rotary
machine: how many sampled angles fit at each position, and a few angle
slices); the components of P in colour; and, for several layers, the lost
area per layer. Figures are PNG files beside the page and embedded in it, so
the page can be mailed alone.

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
from printability.geometry import Raster, polygons_of

__all__ = ["lost_pieces", "write_report"]

_COLORS = {"target": "#d9d9d9", "as_built": "#4c9be8", "lost": "#e8514c", "p": "#2ca25f",
           "uncertain": "#f0a030"}


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


def _draw(ax, geom: BaseGeometry | None, color: str, *, alpha: float = 1.0, label=None,
          zorder: float = 1.0, edge: str = "none") -> None:
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    if geom is None or geom.is_empty:
        return
    for k, poly in enumerate(polygons_of(geom)):
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


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def _worst_layer(n: NozzleAnalysis) -> LayerOutcome:
    return max(n.layers, key=lambda o: (o.lost_area, -o.index))


def _fig_layer(plt, o: LayerOutcome, target: BaseGeometry, title: str) -> bytes:
    from matplotlib.colors import ListedColormap

    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    r = o.result
    if r is not None and r.as_built is not None:
        _draw(ax, r.as_built, _COLORS["as_built"], label="as built (S)")
        # an edge keeps thin lost slivers visible at page scale
        lost, salient = lost_pieces(target, r.as_built, resolution=r.resolution)
        # a raster engine's vector S is its certified inner bound: what it leaves out is
        # lost or merely uncertain (the reported loss is an estimate inside the bounds)
        inner = abs(r.as_built.area - r.as_built_area) > 1e-6 * max(1.0, r.target_area)
        color = _COLORS["uncertain"] if inner else _COLORS["lost"]
        label = ("G \\ S_inner: lost or uncertain" if inner else "lost (G \\ S)")
        _draw(ax, lost, color, zorder=3)
        _draw(ax, salient, color, edge=color, label=label, zorder=3)
        if salient.is_empty:
            ax.plot([], [], color=color, lw=8, label=label)
    else:
        _draw(ax, target, _COLORS["lost"], label="lost (G \\ S)", zorder=0)
        if r is not None and r.as_built_raster is not None:
            # S known only as pixels: paint them over the target in the as-built colour
            _show_raster(ax, Raster(r.as_built_raster.grid,
                                    r.as_built_raster.data.astype(np.uint8)),
                         ListedColormap([_COLORS["as_built"]]))
            ax.plot([], [], color=_COLORS["as_built"], lw=8, label="as built (S, pixels)")
    _frame(ax, target)
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8, framealpha=0.8)
    data = _png(fig)
    plt.close(fig)
    return data


def _fig_motion(plt, o: LayerOutcome, target: BaseGeometry, title: str) -> bytes | None:
    r = o.result
    if r is None:
        return None
    m = r.motion
    angles = np.asarray(m.angles)
    n_slices = min(3, len(angles)) if len(angles) > 1 else 0
    fig, axes = plt.subplots(1, 1 + n_slices, figsize=(5.5 * (1 + n_slices), 5), squeeze=False)
    ax = axes[0, 0]
    _draw(ax, target, _COLORS["target"], zorder=0)
    if m.count is not None:
        im = _show_raster(ax, m.count, "viridis")
        fig.colorbar(im, ax=ax, shrink=0.8, label="angles that fit")
        ax.set_title(f"P: where how many of {len(angles)} angles fit")
    elif m.regions is not None:
        if len(m.regions) == 1:
            _draw(ax, m.regions[0], _COLORS["p"])
            ax.set_title("P: positions of the nozzle origin")
        else:
            # count of angles per position, drawn as overlapping translucent layers
            alpha = max(0.02, min(0.5, 3.0 / len(m.regions)))
            for reg in m.regions:
                _draw(ax, reg, _COLORS["p"], alpha=alpha)
            ax.set_title(f"P over {len(angles)} angles (darker: more angles fit)")
    _frame(ax, target)
    for j in range(n_slices):
        k = round(j * (len(angles) - 1) / max(1, n_slices - 1)) if n_slices > 1 else 0
        ax = axes[0, 1 + j]
        _draw(ax, target, _COLORS["target"], zorder=0)
        if m.regions is not None:
            _draw(ax, m.regions[k], _COLORS["p"])
        else:
            mask = _mask_at(m, k)
            if mask is not None:
                from matplotlib.colors import ListedColormap

                _show_raster(ax, Raster(mask.grid, mask.data.astype(np.uint8)),
                             ListedColormap([_COLORS["p"]]))
        _frame(ax, target)
        ax.set_title(f"P at φ = {angles[k]:.1f}°")
    fig.suptitle(title)
    data = _png(fig)
    plt.close(fig)
    return data


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
    _draw(ax, target, _COLORS["target"], zorder=0)
    cmap = plt.get_cmap("tab20")
    for i, geom in enumerate(r.components.geometries):
        _draw(ax, geom, cmap(i % 20))
    _frame(ax, target)
    ax.set_title(f"{title}: {r.components.count} component(s) of P")
    data = _png(fig)
    plt.close(fig)
    return data


def _fig_per_layer(plt, analysis: Analysis) -> bytes:
    fig, ax = plt.subplots(figsize=(8, 4))
    for n in analysis.nozzles:
        ax.plot([o.z for o in n.layers], [o.lost_area for o in n.layers], marker=".",
                label=n.nozzle.spec)
    ax.set_xlabel("layer z (mm)")
    ax.set_ylabel("lost area (mm²)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Lost area per layer")
    data = _png(fig)
    plt.close(fig)
    return data


def _geojson(n: NozzleAnalysis, analysis: Analysis) -> dict[str, Any]:
    feats = []
    for o, layer in zip(n.layers, analysis.layers, strict=True):
        geom = None
        if o.result is not None and o.result.as_built is not None:
            geom = o.result.as_built
        elif o.result is None:
            geom = shapely.MultiPolygon()
        if geom is None:
            continue
        feats.append({"type": "Feature", "geometry": mapping(geom),
                      "properties": {"z": layer.z, "height": layer.height,
                                     "as_built_area": o.as_built_area,
                                     "lost_area": o.lost_area, "nozzle": n.nozzle.spec}})
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


def _mesh(n: NozzleAnalysis, analysis: Analysis) -> bytes | None:
    import trimesh

    parts = []
    for o, layer in zip(n.layers, analysis.layers, strict=True):
        if o.result is None or o.result.as_built is None or layer.height <= 0:
            continue
        for poly in polygons_of(o.result.as_built):
            m = trimesh.creation.extrude_polygon(poly, layer.height)
            m.apply_translation((0, 0, layer.z - layer.height))
            parts.append(m)
    if not parts:
        return None
    return trimesh.util.concatenate(parts).export(file_type="stl")


def _img(name: str, data: bytes, alt: str) -> str:
    b64 = base64.b64encode(data).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{b64}" alt="{html.escape(alt)}">'
            f'<figcaption><a href="{html.escape(name)}">{html.escape(name)}</a></figcaption>'
            "</figure>")


def write_report(analysis: Analysis, out_dir: str | Path) -> Path:
    """Write ``index.html``, PNG figures and the as-built geometry into ``out_dir``.

    Every file is written atomically. Returns the path of ``index.html``.
    """
    from printability.cli.common import write_atomic

    plt = _pyplot()
    out = Path(out_dir)
    sections = []
    rows = []
    for n in analysis.nozzles:
        lo, hi = n.lost_area_bounds
        rows.append(
            f"<tr><td>{n.rank}</td><td><code>{html.escape(n.nozzle.spec)}</code></td>"
            f"<td>{n.lost_area:.4g}</td><td>{100 * n.lost_fraction:.2f}</td>"
            f"<td>[{lo:.4g}, {hi:.4g}]</td><td>{n.components}</td>"
            + (f"<td>{n.volume('lost_area'):.4g}</td>" if analysis.multi_layer else "")
            + "</tr>")
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
        links = []
        gj = _geojson(n, analysis)
        write_atomic(out / f"{slug}_as_built.geojson", json.dumps(gj))
        links.append(f"{slug}_as_built.geojson")
        if worst.result is not None and worst.result.as_built is not None:
            write_atomic(out / f"{slug}_as_built.svg", _svg(worst.result.as_built, target))
            links.append(f"{slug}_as_built.svg")
        if analysis.multi_layer:
            mesh = _mesh(n, analysis)
            if mesh is not None:
                write_atomic(out / f"{slug}_as_built.stl", mesh)
                links.append(f"{slug}_as_built.stl")
        notes = "".join(f"<li>{html.escape(t)}</li>" for t in
                        (worst.result.notes if worst.result is not None else (worst.note,)) if t)
        sections.append(
            f"<section><h2>#{n.rank}: <code>{html.escape(n.nozzle.spec)}</code></h2>"
            f"<p>Lost {n.lost_area:.4g} mm² of {n.target_area:.4g} mm² "
            f"({100 * n.lost_fraction:.2f} %), bounds [{lo:.4g}, {hi:.4g}] mm². "
            f"Figures show the layer that loses most (z = {worst.z:g} mm).</p>"
            f"{''.join(figs)}<ul>{notes}</ul><p>Geometry: "
            + ", ".join(f'<a href="{html.escape(x)}">{html.escape(x)}</a>' for x in links)
            + "</p></section>")
    per_layer = ""
    if analysis.multi_layer:
        data = _fig_per_layer(plt, analysis)
        write_atomic(out / "lost_per_layer.png", data)
        per_layer = _img("lost_per_layer.png", data, "lost area per layer")
    vol_head = "<th>lost mm³</th>" if analysis.multi_layer else ""
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
<p class="key"><span style="background:{_COLORS['as_built']}"></span>as built (S)
<span style="background:{_COLORS['lost']}"></span>lost (G \\ S)
<span style="background:{_COLORS['p']}"></span>motion restriction P</p>
<table><tr><th>rank</th><th>nozzle</th><th>lost mm²</th><th>lost %</th><th>bounds mm²</th>
<th>components</th>{vol_head}</tr>{''.join(rows)}</table>
{per_layer}
{''.join(sections)}
</body></html>
"""
    index = out / "index.html"
    write_atomic(index, page)
    return index
