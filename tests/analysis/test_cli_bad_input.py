"""Malformed input through ``python -m printability analyze``: exit code 1 and one paragraph on
stderr that names the file, where in it (line, header, element) and what is wrong; never a
traceback."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "printability", "analyze", *args,
                           "--no-progress"], capture_output=True, text=True, timeout=300)


def _truncated_gcode(tmp: Path, data: Path) -> Path:
    src = (data / "gcode" / "prusaslicer_2.7.4_spiral_vase.gcode").read_bytes()
    p = tmp / "truncated.gcode"
    p.write_bytes(src[: len(src) - 5000])      # cut inside the trailing configuration block
    return p


def _junk(suffix: str):
    def make(tmp: Path, data: Path) -> Path:
        p = tmp / f"junk{suffix}"
        # deterministic binary noise (no file magic, NUL and control bytes)
        p.write_bytes(bytes((i * 197 + 13) % 256 for i in range(4096)))
        return p
    return make


def _open_svg(tmp: Path, data: Path) -> Path:
    p = tmp / "strokes.svg"
    p.write_text('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 10 10">'
                 '<path d="M0 0 L5 5" stroke="black" fill="none"/>'
                 '<line x1="0" y1="0" x2="3" y2="3" stroke="black"/></svg>')
    return p


def _flat_mesh(tmp: Path, data: Path) -> Path:
    p = tmp / "sheet.stl"
    p.write_text("solid sheet\n" + "".join(
        f"facet normal 0 0 1\nouter loop\nvertex {a}\nvertex {b}\nvertex {c}\nendloop\nendfacet\n"
        for a, b, c in (("0 0 0", "10 0 0", "0 10 0"), ("10 0 0", "10 10 0", "0 10 0")))
        + "endsolid sheet\n")
    return p


def _degenerate_mesh(tmp: Path, data: Path) -> Path:
    p = tmp / "needles.stl"
    tris = [((0, 0, 0), (1, 0, 0), (2, 0, 0)), ((0, 0, 0), (0, 1, 1), (0, 2, 2))]
    body = b"".join(struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *v) for v in t)
                    + b"\0\0" for t in tris)
    p.write_bytes(b"\0" * 80 + struct.pack("<I", len(tris)) + body)
    return p


def _huge_stl(tmp: Path, data: Path) -> Path:
    # a consistent binary STL of 200 million triangles (10 GB), written sparse: no disk used
    n = 200_000_000
    p = tmp / "huge.stl"
    with p.open("wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", n))
        fh.truncate(84 + 50 * n)
    return p


def _lying_stl_header(tmp: Path, data: Path) -> Path:
    src = (data / "stl" / "CalibrationCube.stl").read_bytes()
    p = tmp / "cut.stl"
    p.write_bytes(src[: len(src) // 2])
    return p


CASES = [
    # (maker, extra args, words that must be in the message)
    (_truncated_gcode, [], ["truncated.gcode", "line", "truncated"]),
    (_junk(".gcode"), [], ["junk.gcode", "line ", "binary"]),
    (_junk(".stl"), [], ["junk.stl", "header", "triangles"]),
    (_junk(".svg"), [], ["junk.svg", "line ", "XML"]),
    (_junk(""), [], ["junk", "cannot tell what kind of file"]),
    (_open_svg, [], ["strokes.svg", "no closed shape"]),
    (_flat_mesh, [], ["sheet.stl", "no volume"]),
    (_degenerate_mesh, [], ["needles.stl", "degenerate"]),
    (_lying_stl_header, [], ["cut.stl", "truncated binary STL", "triangles"]),
    (_huge_stl, [], ["huge.stl", "200,000,000 triangles", "memory limit"]),
]


@pytest.mark.parametrize(("make", "extra", "words"), CASES,
                         ids=[c[0].__name__.strip("_") if c[0].__name__ != "make"
                              else "junk" for c in CASES])
def test_malformed_input_is_one_clear_paragraph(shared_data, tmp_path, make, extra, words):
    p = run(str(make(tmp_path, shared_data)), *extra)
    assert p.returncode == 1, (p.stdout, p.stderr)
    # on a fresh install the first command to compile a kernel says so first, on its own line
    err = "\n".join(ln for ln in p.stderr.strip().splitlines()
                    if not ln.startswith("printability: first run since installing:"))
    assert "Traceback" not in err
    assert err.startswith("printability: error:")
    assert "\n\n" not in err and err.count("printability: error:") == 1
    for w in words:
        assert w in " ".join(err.split()), (w, err)


def test_memory_limit_refuses_a_big_map_before_parsing(shared_data):
    p = run(str(shared_data / "japan_10m.geojson"), "--fit", "100", "--max-memory", "4M")
    assert p.returncode == 1
    err = " ".join(p.stderr.split())
    assert "japan_10m.geojson" in err and "4 MiB memory limit" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(("args", "words"), [
    (["--max-memory", "4Q"], ["--max-memory", "'4Q'"]),
    (["--layers", "7"], ["--layers", "layer 7 does not exist"]),
    (["--layers", "a-b"], ["--layers", "'a-b'"]),
    (["--layers", "5:2"], ["no layer selected"]),
])
def test_bad_options_are_one_paragraph(shared_data, args, words):
    p = run(str(shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"), *args)
    assert p.returncode == 1, p.stderr
    err = " ".join(p.stderr.split())
    assert "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
