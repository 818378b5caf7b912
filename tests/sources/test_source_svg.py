"""SVG sources: the shared icons, units, axes, fill rules, curves, XML attacks, Slic3r slices."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh

from printability.errors import FileFormatError
from printability.settings import Settings
from printability.sources.svg import load_svg_layers, load_svg_region

# Filled areas from ../shared/data/SOURCES.md (viewBox units; unitless documents → 1 unit = 1 mm).
ICONS = {
    "bootstrap_gear-fill.svg": (132.0, 1),
    "bootstrap_bug-fill.svg": (128.4, 5),
    "bootstrap_flower1.svg": (111.6, 1),
    "simpleicons_setuptools.svg": (141.6, 2),
    "simpleicons_gnubash.svg": (149.0, 1),
    "gameicons_lorc_dragon-head.svg": (105_068.0, 3),
}


def _svg(tmp_path: Path, body: str, *, root: str = 'viewBox="0 0 100 100"',
         name: str = "t.svg") -> Path:
    path = tmp_path / name
    path.write_text(f'<svg xmlns="http://www.w3.org/2000/svg" {root}>{body}</svg>')
    return path


@pytest.mark.parametrize("name", sorted(ICONS))
def test_shared_icons(shared_data: Path, name: str):
    area, parts = ICONS[name]
    stack = load_svg_layers(shared_data / "svg" / name)
    assert stack.is_planar
    assert stack[0].area == pytest.approx(area, rel=2e-3)
    assert len(stack[0].region.geoms) == parts
    assert any("1 mm" in w for w in stack.meta["warnings"])  # no physical size given


def test_game_icons_background_square_is_dropped(shared_data: Path):
    stack = load_svg_layers(shared_data / "svg" / "gameicons_lorc_dragon-head.svg")
    assert any("background" in w for w in stack.meta["warnings"])
    # SOURCES.md: shape bbox (21.3, 18.7, 492.2, 491.0) in SVG axes; y is flipped: y ↦ 512 − y.
    minx, miny, maxx, maxy = stack[0].region.bounds
    assert (minx, miny, maxx, maxy) == pytest.approx((21.26, 512 - 490.97, 492.17,
                                                      512 - 18.68), abs=0.02)


def test_lone_full_canvas_shape_is_kept(tmp_path: Path):
    stack = load_svg_layers(_svg(tmp_path, '<path d="M0 0h100v100H0z"/>'))
    assert stack[0].area == pytest.approx(10_000.0)
    assert not any("background" in w for w in stack.meta["warnings"])


def test_y_axis_points_up(tmp_path: Path):
    # A square near the top of the page (small SVG y) ends up at large y.
    region = load_svg_region(_svg(tmp_path, '<rect x="10" y="5" width="20" height="10"/>'))
    assert region.bounds == pytest.approx((10.0, 85.0, 30.0, 95.0))


def test_physical_units_and_fit(tmp_path: Path):
    root = 'width="100mm" height="50mm" viewBox="0 0 10 5"'
    path = _svg(tmp_path, '<rect x="1" y="1" width="2" height="2"/>', root=root)
    stack = load_svg_layers(path)
    assert stack[0].area == pytest.approx(400.0)  # 20 mm × 20 mm
    assert not stack.meta["warnings"]
    assert stack[0].region.bounds == pytest.approx((10.0, 20.0, 30.0, 40.0))
    inch = _svg(tmp_path, '<rect width="1" height="1"/>', root='width="2in" height="2in" '
                'viewBox="0 0 2 2"', name="in.svg")
    assert load_svg_layers(inch)[0].area == pytest.approx(25.4**2)
    fitted = load_svg_layers(path, fit=5.0)
    minx, miny, maxx, maxy = fitted[0].region.bounds
    assert max(maxx - minx, maxy - miny) == pytest.approx(5.0)
    # units= gives the size of one px of a unitless document.
    cm = load_svg_layers(_svg(tmp_path, '<rect width="2" height="3"/>', name="u.svg"),
                         units="cm")
    assert cm[0].area == pytest.approx(600.0)


def test_transforms(tmp_path: Path):
    body = ('<g transform="translate(50 50) rotate(30)">'
            '<rect x="-10" y="-5" width="20" height="10" transform="scale(2 1)"/></g>')
    region = load_svg_region(_svg(tmp_path, body))
    assert region.area == pytest.approx(400.0)
    assert (region.centroid.x, region.centroid.y) == pytest.approx((50.0, 50.0))
    ring = np.asarray(region.geoms[0].exterior.coords)
    angles = {round(math.degrees(math.atan2(*(b - a)[::-1])) % 180)
              for a, b in itertools.pairwise(ring)}
    assert angles == {150, 60}  # 30° clockwise on the page = −30° with y up


@pytest.mark.parametrize(("rule", "area"), [("nonzero", 400.0), ("evenodd", 300.0)])
def test_fill_rules_with_nested_squares(tmp_path: Path, rule: str, area: float):
    # Both squares drawn in the same direction: nonzero fills the inner one, evenodd cuts it.
    d = "M0 0H20V20H0Z M5 5H15V15H5Z"
    region = load_svg_region(_svg(tmp_path, f'<path fill-rule="{rule}" d="{d}"/>'))
    assert region.area == pytest.approx(area)


def test_nonzero_respects_direction(tmp_path: Path):
    d = "M0 0H20V20H0Z M5 5V15H15V5Z"  # inner square reversed: a hole under nonzero too
    assert load_svg_region(_svg(tmp_path, f'<path d="{d}"/>')).area == pytest.approx(300.0)


def test_self_intersecting_star(tmp_path: Path):
    pts = [(50 + 40 * math.sin(math.radians(144 * k)), 50 - 40 * math.cos(math.radians(144 * k)))
           for k in range(5)]
    d = "M" + " L".join(f"{x:.6f} {y:.6f}" for x, y in pts) + "Z"
    star = shapely.Polygon(pts)
    hull_like = shapely.make_valid(star)  # GEOS's reading of a bow-tie: the points only
    evenodd = load_svg_region(_svg(tmp_path, f'<path fill-rule="evenodd" d="{d}"/>'))
    nonzero = load_svg_region(_svg(tmp_path, f'<path d="{d}"/>', name="nz.svg"))
    # The pentagon in the middle has winding number 2: filled by nonzero, not by evenodd.
    assert nonzero.area > evenodd.area > 0
    assert evenodd.area == pytest.approx(hull_like.area, rel=1e-6)


@pytest.mark.parametrize("tol", [0.1, 0.01, 0.001])
def test_arcs_and_curves_within_chord_tolerance(tmp_path: Path, tol: float):
    r = 40.0
    body = f'<circle cx="50" cy="50" r="{r}"/>'
    region = load_svg_region(_svg(tmp_path, body), settings=Settings(chord_tolerance=tol))
    ring = shapely.LinearRing(region.geoms[0].exterior)
    # Inscribed polygon: every vertex on the circle, chords at most tol inside.
    assert region.area <= math.pi * r * r
    assert region.area >= math.pi * r * r - 2 * math.pi * r * tol
    assert shapely.Point(50, 50).distance(ring) >= r - tol - 1e-9
    # An elliptical arc path and a cubic: same bound on the deviation.
    d = "M10 50 A40 20 0 0 1 90 50 C90 80 10 80 10 50Z"
    reg2 = load_svg_region(_svg(tmp_path, f'<path d="{d}"/>', name="c.svg"),
                           settings=Settings(chord_tolerance=tol))
    fine = load_svg_region(_svg(tmp_path, f'<path d="{d}"/>', name="c.svg"),
                           settings=Settings(chord_tolerance=1e-5))
    assert reg2.hausdorff_distance(fine) <= tol * 1.01 + 1e-5


def test_hidden_and_unfilled_elements_are_ignored(tmp_path: Path):
    body = ('<rect width="10" height="10"/>'
            '<rect x="50" width="10" height="10" fill="none" stroke="black"/>'
            '<rect x="70" width="10" height="10" style="display:none"/>'
            '<rect x="20" width="10" height="10" fill-opacity="0"/>'
            '<text x="0" y="50">hello</text>')
    stack = load_svg_layers(_svg(tmp_path, body))
    assert stack[0].area == pytest.approx(100.0)
    assert any("text" in w for w in stack.meta["warnings"])


def test_defs_symbols_and_use(tmp_path: Path):
    body = ('<defs><rect id="r" width="10" height="10"/>'
            '<clipPath id="c"><rect width="50" height="50"/></clipPath></defs>'
            '<symbol id="s"><circle cx="5" cy="5" r="3"/></symbol>'
            '<use href="#r" x="20" y="20"/><use href="#r" x="40" y="20"/>')
    assert load_svg_region(_svg(tmp_path, body)).area == pytest.approx(200.0)
    used = body + '<use href="#s" x="60" y="60"/>'
    region = load_svg_region(_svg(tmp_path, used, name="used.svg"))
    assert region.area == pytest.approx(200.0 + math.pi * 9, rel=1e-3)


def test_stroked_outline_drawing_is_filled(tmp_path: Path):
    body = '<path d="M0 0H30V10H0Z" fill="none" stroke="black"/>'
    stack = load_svg_layers(_svg(tmp_path, body))
    assert stack[0].area == pytest.approx(300.0)
    assert any("stroked" in w for w in stack.meta["warnings"])


def test_no_closed_shape(tmp_path: Path):
    path = _svg(tmp_path, '<line x1="0" y1="0" x2="10" y2="10" stroke="black"/>'
                '<path d="M0 0L10 10" fill="none" stroke="red"/>')
    with pytest.raises(FileFormatError, match=r"t\.svg: no closed shape"):
        load_svg_layers(path)
    with pytest.raises(FileFormatError, match="no closed shape"):
        load_svg_layers(_svg(tmp_path, "", name="empty.svg"))


def test_billion_laughs_is_refused(tmp_path: Path):
    lol = "".join(f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">' for i in range(1, 10))
    path = tmp_path / "lol.svg"
    path.write_text(f'<?xml version="1.0"?><!DOCTYPE svg [<!ENTITY lol0 "lol">{lol}]>'
                    '<svg xmlns="http://www.w3.org/2000/svg"><text>&lol9;</text></svg>')
    with pytest.raises(FileFormatError, match=r"lol\.svg.*refused.*entit"):
        load_svg_layers(path)


def test_external_entity_is_refused(tmp_path: Path):
    path = tmp_path / "xxe.svg"
    path.write_text('<?xml version="1.0"?><!DOCTYPE svg [<!ENTITY x SYSTEM '
                    '"file:///etc/passwd">]><svg xmlns="http://www.w3.org/2000/svg">'
                    '<text>&x;</text></svg>')
    with pytest.raises(FileFormatError, match=r"xxe\.svg.*refused"):
        load_svg_layers(path)


def test_not_xml_and_wrong_root(tmp_path: Path):
    bad = tmp_path / "bad.svg"
    bad.write_text('<svg xmlns="http://www.w3.org/2000/svg">\n<rect width="1"\n</svg>')
    with pytest.raises(FileFormatError, match=r"bad\.svg, line \d+: expected well-formed XML"):
        load_svg_layers(bad)
    html = tmp_path / "page.svg"
    html.write_text("<html><body/></html>")
    with pytest.raises(FileFormatError, match="expected an <svg> root element; found <html>"):
        load_svg_layers(html)
    junk = tmp_path / "junk.svg"
    junk.write_bytes(np.random.default_rng(2).bytes(2000))
    with pytest.raises(FileFormatError, match=r"junk\.svg"):
        load_svg_layers(junk)


def test_memory_estimate_refuses_large_files(shared_data: Path):
    from printability.errors import ResourceError

    with pytest.raises(ResourceError, match="memory limit"):
        load_svg_layers(shared_data / "svg" / "bootstrap_flower1.svg",
                        settings=Settings(max_memory=100_000))


# ---------------------------------------------------------------- Slic3r slice SVG
# Written in the two layouts of Slic3r's writers (the Perl ≤1.2 export_svg and the C++
# SVGExport), from sections computed by trimesh itself, an independent slicer.


def _cube_with_hole() -> trimesh.Trimesh:
    outer = trimesh.creation.box((20.0, 10.0, 2.0))
    hole = trimesh.creation.cylinder(radius=2.0, height=3.0, sections=24)
    solid = outer.difference(hole)
    solid.apply_translation(-solid.bounds[0])
    return solid


def _trimesh_sections(mesh, zs):
    out = []
    for z in zs:
        path = mesh.section(plane_origin=[0, 0, z], plane_normal=[0, 0, 1])
        planar, tf = path.to_2D()
        polys = [shapely.affinity.affine_transform(
            p, [tf[0, 0], tf[0, 1], tf[1, 0], tf[1, 1], tf[0, 3], tf[1, 3]])
            for p in planar.polygons_full]
        out.append(polys)
    return out


def _slic3r_svg(path: Path, layers, zs, *, perl: bool) -> None:
    rows = ['<?xml version="1.0" encoding="UTF-8" standalone="yes"?>',
            '<!DOCTYPE svg PUBLIC "-//W3C//DTD SVG 1.0//EN" '
            '"http://www.w3.org/TR/2001/REC-SVG-20010904/DTD/svg10.dtd">',
            '<svg width="20" height="10" xmlns="http://www.w3.org/2000/svg" '
            'xmlns:svg="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
            'xmlns:slic3r="http://slic3r.org/namespaces/slic3r">',
            "<!-- Generated using Slic3r -->"]
    for i, (polys, z) in enumerate(zip(layers, zs, strict=True)):
        rows.append(f'  <g id="layer{i}" slic3r:z="{z}">')
        for poly in polys:
            rings = [poly.exterior, *poly.interiors]
            if perl:
                for k, ring in enumerate(rings):
                    pts = " ".join(f"{x},{y}" for x, y in ring.coords[:-1])
                    kind = "contour" if k == 0 else "hole"
                    fill = "white" if k == 0 else "black"
                    rows.append(f'    <polygon slic3r:type="{kind}" points="{pts}" '
                                f'style="fill: {fill}" />')
            else:
                d = " ".join("M " + " ".join(f"{x} {y}" for x, y in ring.coords[:-1]) + " z"
                             for ring in rings)
                rows.append(f'    <path d="{d}" style="fill: white; stroke: black; '
                            f'stroke-width: 0; fill-type: evenodd" slic3r:area="{poly.area}" />')
        if perl:
            rows.append('    <line x1="1" y1="1" x2="2" y2="2" '
                        'style="stroke-width: 2; stroke: white" />')
        rows.append("  </g>")
    rows.append("</svg>")
    path.write_text("\n".join(rows))


@pytest.mark.parametrize("perl", [False, True], ids=["cpp-paths", "perl-polygons"])
def test_slic3r_slice_svg(tmp_path: Path, perl: bool):
    mesh = _cube_with_hole()
    first, lh = 0.3, 0.2
    tops = np.array([0.3, 0.5, 0.7, 0.9, 1.1, 1.3, 1.5, 1.7, 1.9])
    hs = np.diff([0.0, *tops])
    mids = tops - hs / 2
    sections = _trimesh_sections(mesh, mids)
    path = tmp_path / "slices.svg"
    _slic3r_svg(path, sections, mids if perl else tops, perl=perl)
    stack = load_svg_layers(path)
    assert len(stack) == len(tops)
    np.testing.assert_allclose([lay.z for lay in stack], tops, atol=1e-9)
    np.testing.assert_allclose([lay.height for lay in stack], [first] + [lh] * 8, atol=1e-9)
    expected = 200.0 - sum(p.area for p in sections[0][:0]) - shapely.Polygon(
        np.asarray(sections[0][0].interiors[0].coords)).area
    for lay, polys in zip(stack, sections, strict=True):
        assert lay.area == pytest.approx(sum(p.area for p in polys), rel=1e-9)
        assert lay.area == pytest.approx(expected, rel=1e-9)
    assert stack.meta["format"] == "slic3r-svg"
    assert ("Perl" in stack.meta["writer"] or "<= 1.3" in stack.meta["writer"]) == perl
    assert not stack.meta["warnings"]  # z in mm: nothing rescaled
    with pytest.raises(FileFormatError, match="9 layers"):
        load_svg_region(path)
