"""Numbers that are not finite or out of any sensible range are refused where they enter (a
CLI option, a nozzle or machine SPEC), with one paragraph and exit 1, never a traceback or an
allocation of terabytes."""

from __future__ import annotations

import subprocess
import sys

import pytest

SQUARE = "POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))"
ELLIPSE = "ellipse:major=0.8,minor=0.3"


@pytest.mark.parametrize(("args", "match"), [
    (["--resolution", "inf"], "resolution"),
    (["-n", "circle:d=1e-300"], "between 0.001 and 1000 mm"),
    (["-n", "circle:d=1e300"], "between 0.001 and 1000 mm"),
    (["-n", f"{ELLIPSE},angle=1e308", "-m", "ttr"], "within ±3600 degrees"),
    (["-n", f"{ELLIPSE},x=1e300", "-m", "ttr"], "offset within"),
    (["-m", "ttr:min=nan"], "rotary min must be a finite"),
    (["-m", "ttr:step=1e-9", "-n", ELLIPSE], "rotary step must be at least 0.001"),
    (["-n", ELLIPSE, "-m", "ttr", "--angle-step", "1e-9"], "angle_step"),
    (["--max-memory", "1e400G"], "--max-memory expects"),
])
def test_analyze_refuses(tmp_path, args, match):
    src = tmp_path / "square.wkt"
    src.write_text(SQUARE)
    r = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src), *args,
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert match in " ".join(r.stderr.split())


@pytest.mark.parametrize(("opt", "value"), [("--tolerance", "nan"), ("--tolerance", "5"),
                                            ("--layer-height", "inf")])
def test_postprocess_refuses(prusa_short_copy, opt, value):
    before = prusa_short_copy.read_bytes()
    r = subprocess.run([sys.executable, "-m", "printability", "postprocess",
                        str(prusa_short_copy), "-n", ELLIPSE, opt, value],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode in (1, 2) and "Traceback" not in r.stderr, r.stderr
    assert prusa_short_copy.read_bytes() == before


@pytest.fixture
def prusa_short_copy(shared_data, tmp_path):
    src = (shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode").read_bytes()
    p = tmp_path / "part.gcode"
    p.write_bytes(src[:src.index(b";LAYER_CHANGE", 20000)])
    return p


@pytest.mark.parametrize(("name", "text", "match"), [
    ("nan.wkt", "POLYGON ((0 0, 10 0, 10 nan, 0 10, 0 0))", "not finite"),
    ("inf.wkt", "POLYGON ((0 0, inf 0, 10 10, 0 10, 0 0))", "not finite"),
    ("huge.wkt", "POLYGON ((0 0, 1e308 0, 10 10, 0 10, 0 0))", "out of range"),
    ("huge.geojson", '{"type":"Polygon","coordinates":[[[0,0],[1e308,0],[10,10],[0,0]]]}',
     "out of range"),
    # a JSON integer of 400 digits is no float (OverflowError, found by the hypothesis suite)
    ("digits.geojson", '{"type":"Polygon","coordinates":[[[0,0],[' + "9" * 400
     + ',0],[10,10],[0,0]]]}', "out of range"),
])
def test_drawings_with_absurd_coordinates(tmp_path, name, text, match):
    src = tmp_path / name
    src.write_text(text)
    r = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src),
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "Warning" not in r.stderr and match in " ".join(r.stderr.split())


def test_fit_out_of_range(shared_data):
    r = subprocess.run([sys.executable, "-m", "printability", "analyze",
                        str(shared_data / "japan_110m.geojson"), "--fit", "1e308",
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "--fit expects" in r.stderr


@pytest.mark.parametrize(("body", "match"), [
    ('width="1e308mm" height="10mm" viewBox="0 0 10 10"><rect x="0" y="0" width="5" '
     'height="5"/>', "mm per user unit"),
    ('viewBox="0 0 10 10"><path d="M0 0 C 1e308 0 10 10 0 10 Z"/>', "out of range"),
])
def test_svg_with_absurd_numbers(tmp_path, body, match):
    src = tmp_path / "bad.svg"
    src.write_text(f'<svg xmlns="http://www.w3.org/2000/svg" {body}</svg>')
    r = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src),
                        "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert match in " ".join(r.stderr.split())


@pytest.mark.parametrize(("value", "match"), [(-1.8446744e20, "out of range"),
                                              (1e16, "out of range")])
def test_a_mesh_with_an_absurd_vertex(tmp_path, value, match):
    """A binary STL whose vertex has a flipped exponent bit (found by the fuzz suite): trimesh
    warned with its source path, then the error spoke of a box 1.8e20 mm tall."""
    import numpy as np

    verts = np.array([[0, 0, 0], [20, 0, 0], [0, 20, 0], [0, 0, 20]], float)
    faces = [(0, 2, 1), (0, 1, 3), (1, 2, 3), (0, 3, 2)]
    tri = np.array([verts[list(f)] for f in faces], np.float32)
    tri[1, 2, 1] = value  # one coordinate of one triangle's corner
    rec = np.zeros(len(tri), dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)),
                                    ("attr", "<u2")])
    rec["v"] = tri
    src = tmp_path / "tetra.stl"
    src.write_bytes(b"\0" * 80 + np.uint32(len(tri)).tobytes() + rec.tobytes())
    r = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src),
                        "--layer-height", "5", "--no-progress"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "Warning" not in r.stderr, r.stderr
    assert r.stderr.startswith("printability: error: ") and match in r.stderr, r.stderr
