"""Layer sources: every input a user brings, read into a
:class:`~printability.model.layers.LayerStack`.

:func:`load_layers` picks the reader from the file's extension, or from its
first bytes when the extension says nothing (or ``format=`` forces one of
:data:`printability.options.SOURCE_FORMATS`):

============================  ==========================================  ====================
extension                     reader (in :mod:`printability.sources`)     layers
============================  ==========================================  ====================
.gcode .gco .g .bgcode        :func:`.gcode.load_gcode_layers`            from the extrusions
.stl .3mf .obj                :func:`.mesh.load_mesh_layers`              sliced at mid-height
.svg                          :func:`.svg.load_svg_layers`                1 (Slic3r's: many)
.dxf                          :func:`.dxf.load_dxf_layers`                1
.geojson .json                :func:`.geo.load_geojson_layers`            1
.wkt                          :func:`.geo.load_wkt_layers`                1
.txt (slice outlines)         :func:`.slices.load_slice_layers`           1
============================  ==========================================  ====================

Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7) is recognised by its first bytes (``GCDE``)
whatever its extension, and read as the G-code it holds (:func:`gcode.bgcode.decode_bgcode`:
every block's CRC checked, the G-code blocks decompressed and MeatPack-decoded): the layers
are those of the same G-code as text.

Planar sources give one layer at z = 0 of height 0 (:attr:`LayerStack.is_planar`).
All coordinates come out in mm; what each reader assumed (units, background
shapes, projection...) is listed in ``LayerStack.meta["warnings"]``.
Every reader refuses coordinates that are not finite or beyond :data:`MAX_COORDINATE`
(:func:`check_coordinates`, which nozzle outline files go through too).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcode.bgcode import is_bgcode
from printability.errors import FileFormatError, InputError, PrintabilityOSError, excerpt
from printability.model.layers import LayerStack
from printability.options import SOURCE_FORMATS
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import MAX_COORDINATE, check_coordinates, option_name

__all__ = ["EXTENSIONS", "MAX_COORDINATE", "check_coordinates", "detect_format", "load_layers"]

EXTENSIONS: dict[str, str] = {
    ".gcode": "gcode", ".gco": "gcode", ".g": "gcode", ".bgcode": "gcode",
    ".stl": "stl", ".3mf": "3mf", ".obj": "obj",
    ".svg": "svg",
    ".dxf": "dxf",
    ".geojson": "geojson", ".json": "geojson",
    ".wkt": "wkt",
    ".txt": "slices",
}
"""File extension → source format (a name of :data:`printability.options.SOURCE_FORMATS`)."""

_WKT_WORDS = (b"POLYGON", b"MULTIPOLYGON", b"GEOMETRYCOLLECTION")


def _sniff(head: bytes, size: int) -> str | None:
    """Guess a format from the first bytes of a file (None when unsure)."""
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    upper = text[:40].upper()
    if text.startswith(b"<"):
        if b"<svg" in head or b"svg" in head[:4096]:
            return "svg"
        return None
    if text.startswith((b"{", b"[")):
        return "geojson"
    if upper.startswith(_WKT_WORDS):
        return "wkt"
    if text.startswith(b"PK\x03\x04"):
        return "3mf"
    if len(head) >= 84 and size == 84 + 50 * int.from_bytes(head[80:84], "little"):
        return "stl"
    if text[:5].lower() == b"solid":
        return "stl"
    lines = text.split(b"\n", 3)
    if len(lines) >= 2 and lines[0].strip() == b"0" and lines[1].strip() == b"SECTION":
        return "dxf"
    from printability.sources.slices import looks_like_slices

    if looks_like_slices(text):
        return "slices"
    if b"G1 " in head or b"G0 " in head or b"\nG28" in head or b";LAYER" in head:
        return "gcode"
    return None


def detect_format(path: str | Path) -> str:
    """The source format of ``path``: from its extension, else from its content (binary
    G-code, starting with ``GCDE``, is ``"gcode"`` whatever its extension).

    Raises
    ------
    PrintabilityOSError
        The file does not exist or cannot be read.
    FileFormatError
        Neither the extension nor the content says what the file is.
    """
    p = Path(path)
    if not p.is_file():
        raise PrintabilityOSError(f"{p}: no such file" if not p.exists()
                                  else f"{p}: not a regular file")
    fmt = EXTENSIONS.get(p.suffix.lower())
    try:
        with p.open("rb") as fh:
            head = fh.read(8192)
        size = p.stat().st_size
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if is_bgcode(head):  # binary G-code, whatever the file is called
        fmt = "gcode"
    elif fmt is None:
        fmt = _sniff(head, size)
    if fmt is None:
        known = ", ".join(sorted(EXTENSIONS))
        raise FileFormatError(
            p, "cannot tell what kind of file this is from its extension "
            f"{excerpt(p.suffix, 20)} or its first bytes; expected one of {known} (give the "
            "file one of these extensions; from Python, load_layers(..., format=) takes one "
            f"of {', '.join(SOURCE_FORMATS.choices)})")
    return fmt


def load_layers(
    path: str | Path,
    *,
    format: str | None = None,
    layer_height: float | None = None,
    first_layer_height: float | None = None,
    units: str | None = None,
    fit: float | None = None,
    map_scale: float | None = None,
    geographic: bool | None = None,
    clip: Sequence[float] | None = None,
    keep_largest: int | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read any supported input as layers (see the module table).

    Parameters
    ----------
    path
        The input file.
    format
        Force a reader (one of :data:`printability.options.SOURCE_FORMATS`);
        by default from the extension, else the content.
    layer_height, first_layer_height
        Slicing of meshes, mm (default 0.2; first layer = layer height).
    units
        Unit of the file's coordinates when the file does not say (one of
        :data:`printability.options.UNITS`); not for G-code or lon/lat data.
    fit
        Scale so the longest side of the part is ``fit`` mm.
    map_scale
        Geographic GeoJSON only: mm on the print per km on the ground.
    geographic
        GeoJSON only: force (True) or deny (False) reading coordinates as lon/lat.
    clip, keep_largest
        GeoJSON/WKT only: keep what lies in a box (file coordinates) / the N
        largest polygons.
    settings
        Tolerances, memory limit and progress display.

    Returns
    -------
    LayerStack

    Raises
    ------
    FileFormatError, InputError, PrintabilityOSError, ResourceError
        With a message naming the file and what was wrong.
    """
    p = Path(path)
    fmt = SOURCE_FORMATS.check(format) if format is not None else detect_format(p)
    given = {"layer_height": layer_height, "first_layer_height": first_layer_height,
             "units": units, "fit": fit, "map_scale": map_scale, "geographic": geographic,
             "clip": clip,
             "keep_largest": keep_largest}

    def only(*allowed: str) -> None:
        extra = [k for k, v in given.items() if v is not None and k not in allowed]
        if extra:
            raise InputError(f"{p}: option(s) {', '.join(map(option_name, extra))} do not "
                             f"apply to {fmt} input"
                             + (f"; it accepts {', '.join(map(option_name, allowed))}"
                                if allowed else ""))

    kw: dict[str, Any] = {"settings": settings}
    if fmt == "gcode":
        only()
        try:
            from printability.sources.gcode import load_gcode_layers
        except ModuleNotFoundError as exc:
            if exc.name != "printability.sources.gcode":
                raise
            raise InputError(f"{p}: this installation cannot read G-code (the module "
                             "printability.sources.gcode is missing)") from None
        return load_gcode_layers(p, settings=settings)
    if fmt in ("stl", "3mf", "obj"):
        only("layer_height", "first_layer_height", "units", "fit")
        from printability.sources.mesh import load_mesh_layers

        return load_mesh_layers(p, file_type=fmt, layer_height=layer_height,
                                first_layer_height=first_layer_height, units=units, fit=fit,
                                **kw)
    if fmt in ("svg", "slic3r-svg"):
        only("units", "fit")
        from printability.sources.svg import load_svg_layers

        return load_svg_layers(p, units=units, fit=fit, **kw)
    if fmt == "dxf":
        only("units", "fit")
        from printability.sources.dxf import load_dxf_layers

        return load_dxf_layers(p, units=units, fit=fit, **kw)
    if fmt == "geojson":
        only("units", "fit", "map_scale", "geographic", "clip", "keep_largest")
        from printability.sources.geo import load_geojson_layers

        return load_geojson_layers(p, units=units, fit=fit, map_scale=map_scale,
                                   geographic=geographic, clip=clip, keep_largest=keep_largest,
                                   **kw)
    if fmt == "wkt":
        only("units", "fit", "clip", "keep_largest")
        from printability.sources.geo import load_wkt_layers

        return load_wkt_layers(p, units=units, fit=fit, clip=clip,
                               keep_largest=keep_largest, **kw)
    only("units", "fit")
    from printability.sources.slices import load_slice_layers

    return load_slice_layers(p, units=units, fit=fit, **kw)
