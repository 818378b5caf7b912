"""STL / 3MF / OBJ sources: slicing, units, repair, refusals, on the shared test parts."""

from __future__ import annotations

import functools
import math
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh

from printability.errors import FileFormatError, ResourceError, UnknownOptionError
from printability.settings import Settings
from printability.sources.mesh import (
    layer_heights,
    load_mesh,
    load_mesh_layers,
    section_region,
)

# From ../shared/data/SOURCES.md (bbox extents and volumes measured there independently).
STL = {
    "CalibrationCube.stl": ((20, 20, 20), 7882),
    "ThinWall.stl": ((50, 50, 5), 863),
    "Tolerance.stl": ((60, 12, 17.8), 9652),
    "HoleTest.stl": ((62.3, 60.4, 5), 2728),
    "3DBenchy_lowpoly.stl": ((59.99, 31.05, 48.02), 15533),
}


@functools.cache
def _stack(path: Path):
    return load_mesh_layers(path, layer_height=0.2)


@pytest.mark.parametrize("name", sorted(STL))
def test_shared_stl_slices_to_its_volume(shared_data: Path, name: str):
    extents, volume = STL[name]
    stack = _stack(shared_data / "stl" / name)
    assert stack.meta["extents"] == pytest.approx(extents, abs=0.03)
    assert stack.meta["volume"] == pytest.approx(volume, rel=1e-3)
    # Σ area·h of mid-height sections is a midpoint-rule integral of the volume.
    assert stack.volume == pytest.approx(volume, rel=0.01)
    assert len(stack) == math.ceil(extents[2] / 0.2 - 0.5)
    assert stack[0].z == pytest.approx(0.2) and stack[0].height == pytest.approx(0.2)
    assert all(layer.region.is_valid for layer in stack)
    assert not stack.meta["warnings"]  # all are mm-sized, closed parts


@pytest.mark.parametrize("name", sorted(STL))
def test_sections_match_trimesh(shared_data: Path, name: str):
    # Oracle: trimesh's own section + polygon assembly, independent of our cut and loops.
    mesh, _ = load_mesh(shared_data / "stl" / name)
    z0, z1 = mesh.bounds[:, 2]
    # The decimated Benchy intersects itself: its sections hold tiny bow-tie loops that
    # shapely repairs (lobes kept) where trimesh keeps a signed area: up to 0.05 mm² apart.
    tol = 0.1 if "Benchy" in name else 1e-6
    for z in np.linspace(z0, z1, 7)[1:-1] + 0.0123:
        ours = section_region(mesh, z).area
        path = mesh.section(plane_origin=[0, 0, z], plane_normal=[0, 0, 1])
        theirs = sum(p.area for p in path.to_2D()[0].polygons_full)
        assert ours == pytest.approx(theirs, abs=tol), f"z={z}"


@pytest.mark.slow
def test_large_mesh_volume(tmp_path: Path):
    sphere = trimesh.creation.icosphere(subdivisions=7, radius=25.0)  # 327,680 triangles
    path = tmp_path / "sphere.stl"
    sphere.export(path)
    stack = load_mesh_layers(path, layer_height=0.1)
    assert len(stack) == 500
    assert stack.volume == pytest.approx(sphere.volume, rel=1e-4)


def test_thinwall_section_area(shared_data: Path):
    mesh, _ = load_mesh(shared_data / "stl" / "ThinWall.stl")
    assert section_region(mesh, 2.51).area == pytest.approx(172.68, abs=0.01)
    # The same section reached through the layer stack (ThinWall sits on z = 0): with a
    # 0.21 mm first layer, layer 12 (top 2.61) is cut at its mid-height 2.51.
    stack = load_mesh_layers(shared_data / "stl" / "ThinWall.stl", layer_height=0.2,
                             first_layer_height=0.21)
    layer = stack[12]
    assert layer.meta["slice_z"] == pytest.approx(2.51, abs=1e-6)
    assert (layer.z, layer.height) == pytest.approx((2.61, 0.2))
    assert layer.area == pytest.approx(172.68, abs=0.01)


def test_benchy_section_parts_and_area(shared_data: Path):
    mesh, _ = load_mesh(shared_data / "stl" / "3DBenchy_lowpoly.stl")
    region = section_region(mesh, 20.03)
    assert region.area == pytest.approx(218.22, abs=0.01)
    # The decimated Benchy self-intersects there: repairing the section leaves one
    # 8e-5 mm² speck besides the 5 real parts.
    assert sum(1 for g in region.geoms if g.area > 1e-3) == 5


def test_benchy_stack_is_placed_on_the_bed(shared_data: Path):
    stack = _stack(shared_data / "stl" / "3DBenchy_lowpoly.stl")
    assert stack.meta["z_offset"] == pytest.approx(0.017, abs=1e-3)
    assert stack[-1].z <= 48.02 + 0.2


def test_zero_normals_do_not_matter(shared_data: Path):
    raw = (shared_data / "stl" / "CalibrationCube.stl").read_bytes()
    n = struct.unpack("<I", raw[80:84])[0]
    normals = np.frombuffer(raw[84:], dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", 9),
                                                     ("a", "<u2")]), count=n)["n"]
    assert not normals.any()  # the file really stores all-zero normals
    stack = _stack(shared_data / "stl" / "CalibrationCube.stl")
    # Below the letters engraved in the side faces the section is the full 20 × 20 square;
    # half-way up, the X and Y engravings bite into it.
    assert stack[0].area == pytest.approx(400.0, abs=1e-6)
    assert 380.0 < stack[len(stack) // 2].area < 399.0
    assert stack.volume == pytest.approx(7882, rel=0.01)


def test_plane_through_vertices_is_nudged():
    # |x| + |y| + |z| <= 1: the plane z = 0 passes through the four equatorial vertices.
    v = [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    f = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]]
    octa = trimesh.Trimesh(vertices=v, faces=f, process=False)
    assert octa.is_watertight and octa.volume > 0
    assert section_region(octa, 0.0).area == pytest.approx(2.0, abs=1e-6)


def test_bodies_touching_along_an_edge(tmp_path: Path):
    a = trimesh.creation.box(bounds=[[0, 0, 0], [10, 10, 5]])
    b = trimesh.creation.box(bounds=[[10, 10, 0], [20, 20, 5]])
    path = tmp_path / "touching.stl"
    trimesh.util.concatenate([a, b]).export(path)
    stack = load_mesh_layers(path, layer_height=1.0)
    assert any("more than two triangles" in w for w in stack.meta["warnings"])
    # The two squares meet at one point in every section: the loop walk cannot
    # tell them apart there, the winding-number arrangement can.
    assert [lay.area for lay in stack] == pytest.approx([200.0] * 5)


def test_inches_warning_and_units(shared_data: Path):
    path = shared_data / "stl" / "idler_riser_inches.stl"
    as_mm = load_mesh_layers(path)
    assert any("units='in'" in w for w in as_mm.meta["warnings"])
    as_in = load_mesh_layers(path, units="in")
    assert not as_in.meta["warnings"]
    assert as_in.meta["extents"] == pytest.approx((2.656 * 25.4, 2.953 * 25.4, 0.625 * 25.4),
                                                  abs=0.05)
    assert as_in.meta["volume"] == pytest.approx(1.4878 * 25.4**3, rel=1e-3)
    assert as_in.volume == pytest.approx(as_in.meta["volume"], rel=0.02)
    with pytest.raises(UnknownOptionError, match="mm, cm, m, in"):
        load_mesh_layers(path, units="furlong")


def test_fit_scales_longest_side(shared_data: Path):
    stack = load_mesh_layers(shared_data / "stl" / "idler_riser_inches.stl", fit=100.0)
    assert max(stack.meta["extents"]) == pytest.approx(100.0)


def test_first_layer_height():
    tops, hs = layer_heights(1.0, 0.2, 0.3)
    np.testing.assert_allclose(tops, [0.3, 0.5, 0.7, 0.9])
    np.testing.assert_allclose(hs, [0.3, 0.2, 0.2, 0.2])
    tops, _ = layer_heights(5.0, 0.2)
    assert len(tops) == 25 and tops[-1] == pytest.approx(5.0)
    tops, _ = layer_heights(0.05, 0.2)  # thinner than a layer: still one
    assert len(tops) == 1


def _box_file(tmp_path: Path, name: str, **kw) -> Path:
    mesh = trimesh.creation.box((10.0, 20.0, 4.0))
    path = tmp_path / name
    mesh.export(path, **kw)
    return path


def test_3mf_units_from_file(tmp_path: Path):
    path = _box_file(tmp_path, "box.3mf")
    stack = load_mesh_layers(path, layer_height=0.5, first_layer_height=0.3)
    assert stack.meta["units"] == "millimeter"
    assert stack[0].z == pytest.approx(0.3) and stack[1].z == pytest.approx(0.8)
    assert stack[0].area == pytest.approx(200.0)
    # Same package declaring inches: 25.4 × larger.
    inch = tmp_path / "box_in.3mf"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(inch, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename.endswith(".model"):
                assert b'unit="millimeter"' in data
                data = data.replace(b'unit="millimeter"', b'unit="inch"')
            dst.writestr(item, data)
    stack = load_mesh_layers(inch, layer_height=5.0)
    assert stack.meta["extents"] == pytest.approx((254.0, 508.0, 101.6))
    assert stack[0].area == pytest.approx(200.0 * 25.4**2)


def test_3mf_package_checks(tmp_path: Path):
    notzip = tmp_path / "fake.3mf"
    notzip.write_bytes(b"solid nothing here")
    with pytest.raises(FileFormatError, match=r"fake\.3mf: .*not a zip archive"):
        load_mesh_layers(notzip)
    # A highly compressed model part whose unpacked size would exceed the memory limit.
    bomb = tmp_path / "bomb.3mf"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("3D/3dmodel.model", b" " * (20 << 20))
    assert bomb.stat().st_size < 100_000
    with pytest.raises(ResourceError, match=r"bomb\.3mf.*unpacking"):
        load_mesh_layers(bomb, settings=Settings(max_memory=64 << 20))
    # Entity declarations are refused before any XML parser sees them.
    ent = tmp_path / "entity.3mf"
    with zipfile.ZipFile(ent, "w") as zf:
        zf.writestr("3D/3dmodel.model", '<?xml version="1.0"?><!DOCTYPE m [<!ENTITY a "aa">]>'
                    '<model unit="millimeter"/>')
    with pytest.raises(FileFormatError, match=r"entity\.3mf, 3D/3dmodel\.model: refused"):
        load_mesh_layers(ent)


def test_obj(tmp_path: Path):
    path = _box_file(tmp_path, "box.obj")
    stack = load_mesh_layers(path, layer_height=1.0, units="cm")
    assert stack[0].area == pytest.approx(200.0 * 100)
    assert len(stack) == 40


def test_small_hole_is_filled(tmp_path: Path):
    mesh = trimesh.creation.box((10.0, 10.0, 10.0))
    mesh.update_faces(np.arange(1, len(mesh.faces)))  # drop one triangle
    path = tmp_path / "holed.stl"
    mesh.export(path)
    stack = load_mesh_layers(path, layer_height=1.0)
    assert stack.meta["repairs"] and "filled holes" in stack.meta["repairs"][0]
    assert stack.volume == pytest.approx(1000.0)


def test_open_surface_is_refused(tmp_path: Path):
    mesh = trimesh.creation.cylinder(radius=5.0, height=10.0, sections=32)
    top = mesh.face_normals[:, 2] > 0.99
    mesh.update_faces(~top)  # remove the whole top cap: a 32-gon hole
    path = tmp_path / "cup.stl"
    mesh.export(path)
    with pytest.raises(FileFormatError, match=r"cup\.stl.*not closed"):
        load_mesh_layers(path)
    with pytest.raises(FileFormatError, match="not closed"):
        load_mesh_layers(path, repair=False)


def test_flat_mesh_has_no_volume(tmp_path: Path):
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]],
                           faces=[[0, 1, 2], [0, 2, 3]], process=False)
    path = tmp_path / "flat.stl"
    flat.export(path)
    with pytest.raises(FileFormatError, match=r"flat\.stl.*flat.*no volume"):
        load_mesh_layers(path)


def test_closed_mesh_without_volume(tmp_path: Path):
    # A closed tetrahedron whose four vertices lie in one slanted plane z = x.
    v = [[0, 0, 0], [10, 0, 10], [0, 10, 0], [10, 10, 10]]
    tet = trimesh.Trimesh(vertices=v, faces=[[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
                          process=False)
    path = tmp_path / "sheet.stl"
    tet.export(path)
    with pytest.raises(FileFormatError, match=r"sheet\.stl.*encloses no volume"):
        load_mesh_layers(path)


def test_truncated_stl(shared_data: Path, tmp_path: Path):
    raw = (shared_data / "stl" / "ThinWall.stl").read_bytes()
    path = tmp_path / "cut.stl"
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(FileFormatError, match=r"cut\.stl.*truncated binary STL.*1,628 triangles"):
        load_mesh_layers(path)


def test_binary_junk(tmp_path: Path):
    path = tmp_path / "junk.stl"
    path.write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(FileFormatError, match=r"junk\.stl"):
        load_mesh_layers(path)
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    with pytest.raises(FileFormatError, match="empty"):
        load_mesh_layers(empty)


def test_ascii_stl_garbage(tmp_path: Path):
    path = tmp_path / "bad.stl"
    path.write_text("solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 zero\n")
    with pytest.raises(FileFormatError, match=r"bad\.stl"):
        load_mesh_layers(path)


def test_huge_file_refused_before_reading(tmp_path: Path):
    # A sparse 50 GB binary STL whose header is consistent with its size.
    n = 1_000_000_000
    path = tmp_path / "huge.stl"
    with path.open("wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", n))
        fh.truncate(84 + 50 * n)
    if path.stat().st_blocks * 512 > 1 << 20:
        path.unlink()
        pytest.skip("the temporary file system does not support sparse files")
    with pytest.raises(ResourceError, match=r"huge\.stl.*1,000,000,000 triangles.*max_memory"):
        load_mesh_layers(path)


def test_memory_limit_applies_to_slicing(shared_data: Path):
    with pytest.raises(ResourceError, match="MiB"):
        load_mesh_layers(shared_data / "stl" / "HoleTest.stl",
                         settings=Settings(max_memory=5 << 20))


def test_progress_bar_goes_to_stderr(shared_data: Path, capsys):
    stack = load_mesh_layers(shared_data / "stl" / "ThinWall.stl",
                             settings=Settings(progress=True))
    assert len(stack) == 25
    assert capsys.readouterr().out == ""  # stdout stays clean (slicer post-processing)
