"""`printability analyze` through the real entry point."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "printability", *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)


def test_analyze_a_real_slice_writes_json(shared_data, tmp_path):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    out = tmp_path / "r.json"
    p = run("analyze", src, "-n", "circle:d=0.4", "-n", "circle:d=1.2", "--json", out,
            "--no-progress")
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    specs = [n["spec"] for n in doc["nozzles"]]
    assert specs == ["circle:d=0.4", "circle:d=1.2"]       # smaller loses less
    assert doc["nozzles"][0]["lost_area"] < doc["nozzles"][1]["lost_area"]
    for n in doc["nozzles"]:
        lo, hi = n["lost_area_bounds"]
        assert lo <= n["lost_area"] <= hi
    assert "circle:d=0.4" in p.stdout and "rank" in p.stdout


@pytest.mark.parametrize(
    ("args", "code", "needle"),
    [
        (["analyze", "no/such/file.stl"], 1, "no/such/file.stl"),
        (["analyze", "{slice}", "-n", "hexagon:d=1"], 1, "expected one of"),
        (["analyze", "{slice}", "--engine", "magic"], 1, "exact, raster"),
        (["analyze", "{slice}", "--resolution", "-1"], 1, "resolution"),
        (["analyze"], 2, "Missing argument"),
    ],
)
def test_errors_are_one_paragraph(shared_data, args, code, needle):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    p = run(*[a.replace("{slice}", str(src)) for a in args])
    assert p.returncode == code, (p.stdout, p.stderr)
    assert needle in p.stderr
    assert "Traceback" not in p.stderr
    if code == 1:
        assert p.stderr.strip().startswith("printability: error:")
        assert "\n\n" not in p.stderr.strip()
