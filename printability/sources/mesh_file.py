"""Reading a mesh file (STL, 3MF, OBJ) before it is checked and repaired.

Before trimesh reads a file its size is weighed (:func:`estimate_triangles`:
an STL's header, a 3MF package's parts, an OBJ's bytes) against the memory
limit, and a 3MF package is refused when it is a zip bomb or declares XML
entities; then :func:`read_mesh` loads it as it is (no processing) and
:func:`mesh_units` says the file's unit.
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from printability.errors import FileFormatError, InputError, PrintabilityOSError, excerpt
from printability.sources._common import check_coordinates, check_memory, unit_scale

__all__ = ["BYTES_PER_TRIANGLE", "estimate_triangles", "mesh_units", "read_mesh"]

# Peak bytes per triangle while trimesh loads and processes a mesh (float64 vertices,
# int64 faces, normals, edge tables, merge and adjacency caches).
BYTES_PER_TRIANGLE = 1200
_3MF_UNITS_MM = {"micron": 1e-3, "millimeter": 1.0, "centimeter": 10.0, "inch": 25.4,
                 "foot": 304.8, "meter": 1000.0}


def _stl_triangles(p: Path, size: int) -> int:
    """Triangle count of an STL file from its header and size, or FileFormatError."""
    with p.open("rb") as fh:
        head = fh.read(84)
    if head[:5].lower() == b"solid" and size != 84 + 50 * _declared(head):
        # ASCII STL: check that it is text; ~250 bytes per facet (7 lines).
        with p.open("rb") as fh:
            sample = fh.read(4096)
        if b"\0" in sample or not _is_text(sample):
            raise FileFormatError(p, "starts like ASCII STL ('solid') but holds binary data "
                                  "whose size does not match a binary STL either")
        return max(1, size // 120)
    if size < 84:
        raise FileFormatError(p, f"too short for a binary STL: {size} bytes, fewer than the "
                              "84-byte header; and not ASCII STL (no 'solid')")
    n = _declared(head)
    need = 84 + 50 * n
    if size < need:
        raise FileFormatError(
            p, f"truncated binary STL: the header announces {n:,} triangles ({need:,} bytes) "
            f"but the file has {size:,} bytes ({(size - 84) // 50:,} whole triangles)",
            element="header")
    if n == 0:
        raise FileFormatError(p, "the binary STL header announces 0 triangles; expected a "
                              "mesh", element="header")
    if size > need + 4096:
        raise FileFormatError(
            p, f"not an STL file: as binary STL the header announces {n:,} triangles "
            f"({need:,} bytes) but the file has {size:,} bytes; as ASCII STL it should "
            "start with 'solid'", element="header")
    return n


def _declared(head: bytes) -> int:
    return struct.unpack("<I", head[80:84])[0] if len(head) >= 84 else -1


def _is_text(sample: bytes) -> bool:
    try:
        sample.decode("ascii")
    except UnicodeDecodeError:
        return False
    return True


def _check_3mf(p: Path, limit: int) -> int:
    """Refuse zip bombs and XML entity tricks in a 3MF package; estimate triangles."""
    try:
        with zipfile.ZipFile(p) as zf:
            infos = zf.infolist()
            total = sum(i.file_size for i in infos)
            check_memory(p, total * 12, limit, "unpacking and parsing this 3MF package")
            models = [i for i in infos if i.filename.lower().endswith(".model")]
            if not models:
                raise FileFormatError(p, "a 3MF package must hold a 3D/3dmodel.model part; "
                                      "found none")
            for i in models:
                with zf.open(i) as fh:
                    head = fh.read(65536)
                if b"<!ENTITY" in head or b"<!DOCTYPE" in head:
                    raise FileFormatError(p, "refused: the model part declares a DTD or XML "
                                          "entities, which 3MF does not use and which can "
                                          "expand without bound", element=i.filename)
    except zipfile.BadZipFile:
        raise FileFormatError(p, "expected a 3MF package (a zip archive); the file is not "
                              "a zip archive") from None
    # A <triangle v1=.. v2=.. v3=../> is ~40 bytes of XML.
    return max(1, sum(i.file_size for i in models) // 40)


def estimate_triangles(p: Path, kind: str, size: int, limit: int) -> int:
    """Triangles a mesh file of ``size`` bytes holds, about (for the memory check); refuses
    what is no mesh of its kind, and 3MF zip bombs."""
    if kind == "stl":
        return _stl_triangles(p, size)
    if kind == "3mf":
        return _check_3mf(p, limit)
    return max(1, size // 30)  # OBJ: "f a b c" lines plus "v x y z" lines


def read_mesh(p: Path, kind: str, *, max_memory: int) -> Any:
    """The mesh of file ``p`` of ``kind`` (``stl``, ``3mf``, ``obj``) as trimesh reads it,
    unprocessed: checked to fit ``max_memory`` bytes first, and to hold finite coordinates
    within range."""
    import trimesh

    try:
        size = p.stat().st_size
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if size == 0:
        raise FileFormatError(p, "the file is empty; expected a mesh")
    n_est = estimate_triangles(p, kind, size, max_memory)
    check_memory(p, n_est * BYTES_PER_TRIANGLE, max_memory,
                 f"loading this mesh (about {n_est:,} triangles)")
    if kind == "3mf":
        try:
            import lxml  # noqa: F401  (trimesh's 3MF reader needs it)
        except ImportError:
            raise InputError("reading 3MF files needs the package 'lxml'; install it with "
                             "pip install lxml") from None
    try:
        mesh = trimesh.load(str(p), file_type=kind, force="mesh", process=False)
    except MemoryError:
        raise
    except Exception as exc:  # trimesh's loaders raise many unrelated types on bad input
        raise FileFormatError(p, f"cannot read as {kind.upper()} ({type(exc).__name__}: "
                              f"{exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise FileFormatError(p, f"no triangles found; expected a {kind.upper()} mesh")
    if not np.isfinite(mesh.vertices).all():
        raise FileFormatError(p, "the mesh has non-finite (NaN or infinite) vertex coordinates")
    # before any repair: a vertex at 1.8e20 (a flipped exponent bit) made trimesh's rounding
    # warn with its source path, then "no volume inside a 20 × 1.845e+20 × 20 mm box"
    check_coordinates(p, mesh.vertices)
    return mesh


def mesh_units(p: Path, mesh: Any, kind: str, units: str | None,
               warnings: list[str]) -> tuple[float, str | None]:
    """The scale to mm (``units`` when given, else the 3MF file's unit, else 1) and the
    file's own unit (3MF only, else None); a ``units`` overriding it is noted in
    ``warnings``. The vertices scaled must stay within range."""
    file_units = None
    if kind == "3mf":
        file_units = str(mesh.units or mesh.metadata.get("units") or "millimeter").lower()
    if units is not None:
        k = unit_scale(units)
        if file_units and abs(_3MF_UNITS_MM.get(file_units, 1.0) - k) > 1e-12:
            warnings.append(f"units={units!r} overrides the file's unit {excerpt(file_units)}")
    elif file_units:
        if file_units not in _3MF_UNITS_MM:
            raise FileFormatError(p, f"unknown 3MF unit {excerpt(file_units)}; expected one of "
                                  f"{', '.join(_3MF_UNITS_MM)}", element="model@unit")
        k = _3MF_UNITS_MM[file_units]
    else:
        k = 1.0
    check_coordinates(p, mesh.vertices * k)  # in mm: a unit's scale may take them out of range
    return k, file_units
