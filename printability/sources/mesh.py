"""Triangle meshes (STL, 3MF, OBJ) sliced into layers with trimesh.

Slicing
    The part is placed on the bed as a slicer would: it is shifted so its
    lowest point is at z = 0 (``meta["z_offset"]`` is the shift, mm); x and y
    stay as in the file. Layer tops
    are t₀ = first_layer_height, tᵢ = t₀ + i·layer_height; a layer exists while
    its mid-height is below the part's top (Slic3r's rule). **A layer's region
    is the section of the mesh at the layer's mid-height** (tᵢ − hᵢ/2), what
    Slic3r/PrusaSlicer slice at too; it is the layer's best single estimate and
    never lies on a horizontal facet at a layer boundary. A section plane that
    passes exactly through a vertex is nudged up by a few nanometres so every
    section is a set of simple closed loops. Sections are nested by even-odd
    containment, so facet orientation and stored normals play no part (the
    all-zero normals some writers store, e.g. Cura's, do not matter).

Units
    STL and OBJ carry no units: they are read as mm unless ``units=`` says
    otherwise ("mm", "cm", "m", "in"). When a part read as mm is implausibly
    small (longest side under 10 mm... as a bracket drawn in inches is), a
    warning in ``meta["warnings"]`` suggests ``units="in"``. 3MF files state
    their unit, which is honoured (``units=`` overrides it, with a warning).
    ``fit=MM`` scales the part uniformly so its longest side is MM mm.

Repair
    Vertices are merged, degenerate and duplicate triangles dropped. A mesh
    that is not closed gets its holes filled (:func:`trimesh.repair.fill_holes`);
    if edges bordering a single triangle remain, the mesh is refused with a
    :class:`~printability.errors.FileFormatError` (``repair=False`` refuses at
    once). Edges shared by more than two triangles (bodies touching along an
    edge) are accepted with a warning. An inside-out mesh is turned right side
    out; a mesh that encloses no volume is refused.

Memory
    The triangle count is known from the file size before anything is read
    (binary STL: 50 bytes per triangle); the load and the sections are
    estimated and refused with :class:`~printability.errors.ResourceError` when
    they exceed ``settings.max_memory``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from printability.errors import FileFormatError, InputError
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import (
    check_memory,
    check_positive,
    fill_segments,
    nest_even_odd,
    require_file,
)
from printability.sources.mesh_file import BYTES_PER_TRIANGLE, mesh_units, read_mesh

__all__ = [
    "DEFAULT_LAYER_HEIGHT",
    "MESH_EXTENSIONS",
    "layer_heights",
    "load_mesh",
    "load_mesh_layers",
    "section_region",
]

DEFAULT_LAYER_HEIGHT = 0.2
"""Layer height used when none is given, mm (a common FDM default)."""
MESH_EXTENSIONS = {".stl": "stl", ".3mf": "3mf", ".obj": "obj"}
# Bytes per section segment: 2 float64 points, a shapely LineString, ring assembly.
_BYTES_PER_SEGMENT = 400
_INCH_HINT_MM = 10.0
# Planes cut together: at most this many, and at most _SEGMENTS_PER_BATCH segments.
_PLANES_PER_BATCH = 32
_SEGMENTS_PER_BATCH = 1_000_000


# ---------------------------------------------------------------- loading


def _edge_counts(mesh: Any) -> tuple[int, int]:
    """(edges used by one face, edges used by more than two faces)."""
    e = np.asarray(mesh.edges_sorted, dtype=np.int64)
    if not len(e):
        return 0, 0
    # One int64 key per undirected edge: a 1-D unique is ~10× faster than unique(axis=0).
    _, counts = np.unique(e[:, 0] * (int(e.max()) + 1) + e[:, 1], return_counts=True)
    return int((counts == 1).sum()), int((counts > 2).sum())


def load_mesh(
    path: str | Path,
    *,
    file_type: str | None = None,
    units: str | None = None,
    fit: float | None = None,
    repair: bool = True,
    settings: Settings = DEFAULT_SETTINGS,
) -> tuple[Any, dict[str, Any]]:
    """Load, check and repair a mesh, scaled to mm (not yet placed on the bed).

    Returns
    -------
    mesh, meta
        A closed :class:`trimesh.Trimesh` in mm, and facts about it (``units``,
        ``scale``, ``triangles``, ``repairs``, ``warnings``...).

    Raises
    ------
    FileFormatError
        Unreadable file, not closed after repair, or no volume.
    ResourceError
        The estimated memory exceeds ``settings.max_memory``.
    """
    p = require_file(path)
    kind = file_type or MESH_EXTENSIONS.get(p.suffix.lower())
    if kind not in MESH_EXTENSIONS.values():
        raise InputError(f"{p}: not a mesh file; expected one of "
                         f"{', '.join(MESH_EXTENSIONS)} (or file_type= stl, 3mf, obj)")
    fit = check_positive("fit", fit)
    mesh = read_mesh(p, kind, max_memory=settings.max_memory)
    warnings: list[str] = []
    k, file_units = mesh_units(p, mesh, kind, units, warnings)
    n_read = len(mesh.faces)
    repairs = _repair(p, mesh, k, repair=repair, warnings=warnings)
    if k != 1.0:
        mesh.apply_scale(k)
    f = 1.0
    if fit is not None:
        f = fit / float(mesh.extents.max())
        mesh.apply_scale(f)
    if units is None and file_units is None and fit is None:
        _hint_units(mesh, kind, warnings)
    meta = {
        "format": kind,
        "units": file_units or (units or "mm"),
        "scale": k * f,
        "triangles": len(mesh.faces),
        "triangles_read": n_read,
        "volume": float(mesh.volume),
        "extents": tuple(float(v) for v in mesh.extents),
        "repairs": repairs,
        "warnings": warnings,
    }
    return mesh, meta


def _repair(p: Path, mesh: Any, k: float, *, repair: bool, warnings: list[str]) -> list[str]:
    """Merge vertices, drop degenerate and duplicate triangles, fill holes (``repair``), fix
    the winding; what was done. ``k`` is the file's scale to mm (for the messages)."""
    import trimesh

    repairs = []
    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces()
    if not keep.all():
        repairs.append(f"dropped {int((~keep).sum())} degenerate triangle(s)")
        mesh.update_faces(keep)
    uniq = mesh.unique_faces()
    if uniq.sum() < len(mesh.faces):
        repairs.append(f"dropped {len(mesh.faces) - int(uniq.sum())} duplicate triangle(s)")
        mesh.update_faces(uniq)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise FileFormatError(p, "every triangle is degenerate (zero area): the mesh "
                              "encloses no volume")
    extent = mesh.extents * k
    if not (extent > 0).all():
        raise FileFormatError(p, f"the mesh is flat (extent {extent[0]:.4g} × {extent[1]:.4g} "
                              f"× {extent[2]:.4g} mm): it encloses no volume")
    open_edges, nonmanifold = _edge_counts(mesh)
    if open_edges:
        if not repair:
            raise FileFormatError(p, f"the mesh is not closed: {open_edges} edge(s) border "
                                  "only one triangle; pass repair=True to fill the holes")
        trimesh.repair.fill_holes(mesh)
        after, nonmanifold = _edge_counts(mesh)
        if after:
            raise FileFormatError(
                p, f"the mesh is not closed: {open_edges} edge(s) border only one triangle and "
                f"{after} still do after filling holes; a section of an open surface has no "
                "inside. Repair the mesh (e.g. in a mesh editor or PrusaSlicer's Fix) first")
        repairs.append(f"filled holes bordered by {open_edges} open edge(s)")
    if nonmanifold:
        warnings.append(f"{nonmanifold} edge(s) are shared by more than two triangles "
                        "(bodies touching along an edge); sections there may merge bodies")
    trimesh.repair.fix_winding(mesh)
    with np.errstate(invalid="ignore", divide="ignore"):  # zero volume: centre of mass is 0/0
        vol = float(mesh.volume)
    if vol < 0:
        mesh.invert()
        vol = -vol
        repairs.append("turned inside-out facets right side out")
    if not (vol * k**3 > 1e-9 * float(np.prod(extent))):
        raise FileFormatError(p, f"the mesh encloses no volume ({vol * k**3:.3g} mm³ inside a "
                              f"{extent[0]:.4g} × {extent[1]:.4g} × {extent[2]:.4g} mm box)")
    return repairs


def _hint_units(mesh: Any, kind: str, warnings: list[str]) -> None:
    """A part under 10 mm read from a file without units was probably drawn in inches (or
    metres): say so."""
    longest = float(mesh.extents.max())
    if longest < _INCH_HINT_MM:
        dims = " × ".join(f"{v:.4g}" for v in mesh.extents)
        as_in = " × ".join(f"{v * 25.4:.4g}" for v in mesh.extents)
        hint = (f"the part measures only {dims} mm read as mm; {kind.upper()} has no "
                f"units: if it was drawn in inches ({as_in} mm) pass units='in'")
        if longest < 1.0:
            as_m = " × ".join(f"{v * 1000:.4g}" for v in mesh.extents)
            hint += f", in metres ({as_m} mm) units='m'"
        warnings.append(hint)


# ---------------------------------------------------------------- slicing


def layer_heights(
    height: float, layer_height: float, first_layer_height: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Layer tops and thicknesses for a part ``height`` mm tall.

    Tops t₀ = first, tᵢ = t₀ + i·layer_height while the mid-height tᵢ − h/2 is
    below ``height`` (at least one layer).
    """
    first = layer_height if first_layer_height is None else first_layer_height
    # Layer i ≥ 1 has mid-height first + (i − ½)·layer_height; keep it while below the top.
    n_more = max(0, math.ceil((height - first) / layer_height + 0.5) - 1)
    tops = first + layer_height * np.arange(n_more + 1, dtype=float)
    hs = np.full(len(tops), layer_height)
    hs[0] = first
    return tops, hs


def _nudge(planes: np.ndarray, vz: np.ndarray, scale: float) -> np.ndarray:
    """Move planes off vertex heights so every section is made of simple loops."""
    eps = max(scale, 1.0) * 1e-9
    out = planes.copy()
    for _ in range(8):
        idx = np.clip(np.searchsorted(vz, out), 1, len(vz) - 1)
        near = np.minimum(np.abs(vz[idx] - out), np.abs(vz[idx - 1] - out)) < eps
        if not near.any():
            break
        out[near] += 10 * eps
        eps *= 2
    return out


def _loops(segs: np.ndarray) -> list[np.ndarray] | None:
    """Closed loops from section segments, or None if some point is not on exactly two.

    In a section of a closed 2-manifold by a plane through no vertex every end
    point is shared by exactly two segments. The loops are then the cycles of
    the permutation "leave a segment by its other end", found without a Python
    loop by pointer jumping: cycle labels (the smallest slot) and positions
    (distance to the cycle's end) in O(n log n).
    """
    pts = np.ascontiguousarray(np.round(segs.reshape(-1, 2), 9))
    _, node = np.unique(pts.view(np.complex128).ravel(), return_inverse=True)
    node = node.reshape(-1)
    zero = node[0::2] == node[1::2]
    if zero.any():  # zero-length segments carry no geometry
        keep = np.repeat(~zero, 2)
        pts, node = pts[keep], node[keep]
        _, node = np.unique(node, return_inverse=True)
    n2 = len(node)
    if n2 == 0 or not (np.bincount(node) == 2).all():
        return None
    idx = np.arange(n2)
    pairs = np.argsort(node, kind="stable").reshape(-1, 2)
    partner = np.empty(n2, dtype=np.int64)
    partner[pairs[:, 0]] = pairs[:, 1]
    partner[pairs[:, 1]] = pairs[:, 0]
    # A "slot" is a segment end; entering a segment at slot i, we leave at i ^ 1 and
    # enter the next segment at the slot sharing that point.
    succ = partner[idx ^ 1]
    rounds = int(np.ceil(np.log2(n2))) + 1
    lab, f = idx.copy(), succ.copy()
    for _ in range(rounds):
        lab = np.minimum(lab, lab[f])
        f = f[f]
    # Each loop is two cycles (one per direction): keep the one holding the smaller slot.
    keep = lab < lab[idx ^ 1]
    # Rank within each cycle: cut it before its label, then list-rank by doubling.
    pred = np.empty(n2, dtype=np.int64)
    pred[succ] = idx
    nxt = succ.copy()
    starts = idx[lab == idx]
    nxt[pred[starts]] = -1
    dist = (nxt >= 0).astype(np.int64)
    f = nxt
    for _ in range(rounds):
        ok = f >= 0
        fo = np.where(ok, f, 0)
        dist = np.where(ok, dist + dist[fo], dist)
        f = np.where(ok, f[fo], -1)
    k = idx[keep]
    order = k[np.lexsort((-dist[k], lab[k]))]
    cuts = np.flatnonzero(np.diff(lab[order])) + 1
    return [pts[o] for o in np.split(order, cuts)]


def _section(segs: np.ndarray, area_tol: float) -> list[Any]:
    """Polygons of one section from its segments (m, 2, 2), mm."""
    if not len(segs):
        return []
    loops = _loops(segs)
    if loops is not None:
        return nest_even_odd(loops, min_area=area_tol)
    # Touching loops or near-degenerate cuts: fall back to the exact arrangement.
    snapped = np.round(segs, 9)
    region = fill_segments(snapped[:, 0], snapped[:, 1], "evenodd")
    return [g for g in shapely.get_parts(region) if g.area > area_tol]


def _cut(vertices: np.ndarray, faces: np.ndarray, fz: tuple[np.ndarray, np.ndarray],
         planes: np.ndarray) -> list[np.ndarray]:
    """Section segments (m, 2, 2) of the triangles by each horizontal plane (sorted z).

    Only the (triangle, plane) pairs that cross are computed. Each crossing
    point is computed from its edge's end points in a fixed order (lower vertex
    index first), so the two triangles sharing an edge give bit-identical
    points and the loops close exactly. Planes must avoid vertex heights
    (see :func:`_nudge`).
    """
    zmin, zmax = fz
    lo = np.searchsorted(planes, zmin, side="right")
    hi = np.searchsorted(planes, zmax, side="left")
    count = np.maximum(hi - lo, 0)
    face = np.repeat(np.arange(len(faces)), count)
    # Plane index of each pair: lo[f], lo[f] + 1, ... for every face f.
    starts = np.repeat(np.cumsum(count) - count, count)
    plane = np.repeat(lo, count) + (np.arange(len(face)) - starts)
    order = np.argsort(plane, kind="stable")
    face, plane = face[order], plane[order]
    tri = faces[face]
    z = planes[plane]
    above = vertices[tri, 2] > z[:, None]
    lone_above = above.sum(axis=1) == 1
    a = np.argmax(above == lone_above[:, None], axis=1)  # the vertex alone on its side
    rows = np.arange(len(tri))
    ia, ib, ic = tri[rows, a], tri[rows, (a + 1) % 3], tri[rows, (a + 2) % 3]

    def point(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        u, w = np.minimum(i, j), np.maximum(i, j)
        pu, pw = vertices[u], vertices[w]
        t = (z - pu[:, 2]) / (pw[:, 2] - pu[:, 2])
        return pu[:, :2] + t[:, None] * (pw[:, :2] - pu[:, :2])

    segs = np.stack([point(ia, ib), point(ia, ic)], axis=1)
    bounds = np.searchsorted(plane, np.arange(len(planes) + 1))
    return [segs[bounds[k] : bounds[k + 1]] for k in range(len(planes))]


def _batches(planes: np.ndarray, fz: tuple[np.ndarray, np.ndarray]) -> list[tuple[int, int]]:
    """Plane index ranges [s, e) bounding the segments (memory) and planes per batch."""
    lo = np.searchsorted(planes, fz[0], side="right")
    hi = np.searchsorted(planes, fz[1], side="left")
    per_plane = np.cumsum(np.bincount(lo, minlength=len(planes) + 1)
                          - np.bincount(hi, minlength=len(planes) + 1))[: len(planes)]
    out, s, acc = [], 0, 0
    for k, n in enumerate(per_plane.tolist()):
        if k > s and (k - s >= _PLANES_PER_BATCH or acc + n > _SEGMENTS_PER_BATCH):
            out.append((s, k))
            s, acc = k, 0
        acc += n
    out.append((s, len(planes)))
    return out


def _face_z(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    fz = mesh.vertices[mesh.faces][:, :, 2]
    return fz.min(axis=1), fz.max(axis=1)


def section_region(mesh: Any, z: float, *, settings: Settings = DEFAULT_SETTINGS) -> Any:
    """The section of ``mesh`` by the plane at height ``z`` (mesh coordinates), as a region.

    Raises
    ------
    InputError
        The plane misses the part.
    """
    vz = np.unique(mesh.vertices[:, 2])
    plane = _nudge(np.array([float(z)]), vz, float(mesh.extents.max()))
    segs = _cut(np.asarray(mesh.vertices), np.asarray(mesh.faces), _face_z(mesh), plane)[0]
    polys = _section(segs, settings.area_tolerance)
    return as_region(shapely.MultiPolygon(polys) if polys else shapely.Polygon(),
                     name=f"section at z={z:g}")


def load_mesh_layers(
    path: str | Path,
    *,
    file_type: str | None = None,
    layer_height: float | None = None,
    first_layer_height: float | None = None,
    units: str | None = None,
    fit: float | None = None,
    repair: bool = True,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Slice an STL / 3MF / OBJ mesh into layers (see the module notes).

    Parameters
    ----------
    path
        The mesh file.
    file_type
        ``"stl"``, ``"3mf"`` or ``"obj"``; by default from the extension.
    layer_height
        Layer thickness, mm (default :data:`DEFAULT_LAYER_HEIGHT`).
    first_layer_height
        Thickness of the first layer, mm (default: ``layer_height``).
    units
        Unit of the file's coordinates (STL/OBJ have none; default mm).
    fit
        Scale so the part's longest side is ``fit`` mm.
    repair
        Fill holes of a mesh that is not closed (else refuse it).
    settings
        ``max_memory`` bounds the work; ``progress`` shows a bar across layers.

    Returns
    -------
    LayerStack
        Layers bottom to top, z = layer top above the bed; ``meta`` holds
        ``z_offset`` (mm added to the file's z), ``slice_at = "mid-height"``, the
        load facts of :func:`load_mesh` and ``warnings``.
    """
    lh = check_positive("layer_height", layer_height) or DEFAULT_LAYER_HEIGHT
    flh = check_positive("first_layer_height", first_layer_height) or lh
    mesh, meta = load_mesh(path, file_type=file_type, units=units, fit=fit, repair=repair,
                           settings=settings)
    p = Path(path)
    z_offset = -float(mesh.bounds[0, 2])
    mesh.apply_translation([0.0, 0.0, z_offset])
    height = float(mesh.bounds[1, 2])
    tops, hs = layer_heights(height, lh, flh)
    mids = tops - hs / 2
    if mids[0] >= height:
        mids[0] = height / 2
        meta["warnings"].append(f"the part ({height:.4g} mm) is thinner than half the first "
                                f"layer ({flh:g} mm); its one layer is cut at mid-part")
    # Memory: each triangle yields one segment per plane crossing it.
    fz = _face_z(mesh)
    crossings = (np.searchsorted(mids, fz[1], side="right")
                 - np.searchsorted(mids, fz[0], side="left"))
    n_seg = int(crossings.sum())
    check_memory(p, n_seg * _BYTES_PER_SEGMENT + len(mesh.faces) * BYTES_PER_TRIANGLE,
                 settings.max_memory,
                 f"slicing {len(mids):,} layers ({n_seg:,} section segments)")
    planes = _nudge(mids, np.unique(mesh.vertices[:, 2]), float(mesh.extents.max()))

    layers: list[Layer] = []
    empty = 0
    progress = None
    task = None
    if settings.progress:
        from rich.console import Console
        from rich.progress import Progress

        progress = Progress(console=Console(stderr=True), transient=True)
        progress.start()
        task = progress.add_task(f"slicing {p.name}", total=len(planes))
    try:
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        for s, e in _batches(planes, fz):
            batch = planes[s:e]
            for j, segs in enumerate(_cut(vertices, faces, fz, batch)):
                i = s + j
                polys = _section(segs, settings.area_tolerance)
                if not polys:
                    empty += 1
                    continue
                region = as_region(shapely.MultiPolygon(polys),
                                   name=f"{p}, layer {i} (z={tops[i]:g})")
                layers.append(Layer(z=float(tops[i]), height=float(hs[i]), region=region,
                                    index=len(layers), meta={"slice_z": float(batch[j])}))
            if progress is not None:
                progress.update(task, advance=len(batch))
    finally:
        if progress is not None:
            progress.stop()
    if empty:
        meta["warnings"].append(f"{empty} layer(s) with an empty section were left out")
    if not layers:
        raise FileFormatError(p, "no layer has a section with area; the mesh encloses no "
                              "printable volume at this layer height")
    meta.update(z_offset=z_offset, layer_height=lh, first_layer_height=flh,
                slice_at="mid-height", height=height)
    return LayerStack(tuple(layers), source=str(p), meta=meta)

