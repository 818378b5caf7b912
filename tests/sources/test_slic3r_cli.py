"""The real Slic3r (Debian's slic3r 1.3) slicing the shared STLs to its multi-layer SVG
(``slic3r --export-svg``), read as a layer source and analysed through the command line.

Slic3r 1.3's writer puts ``slic3r:z`` in units of 10⁻⁶ mm (the slicing plane, already in mm,
multiplied by its scaling factor once more): read literally, a 20 mm cube is 20 nm tall and
its lost volume comes out near 10⁻⁶ mm³.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from printability.sources import load_layers


@pytest.fixture(scope="module")
def slic3r() -> str:
    exe = shutil.which("slic3r")
    if exe is None:
        pytest.skip("slic3r is not installed (Debian: apt-get install slic3r); the Slic3r "
                    "SVG tests cannot run")
    return exe


def _export_svg(exe: str, stl: Path, out: Path) -> Path:
    r = subprocess.run([exe, "--export-svg", str(stl), "-o", str(out)], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0 and out.is_file(), (r.stdout + r.stderr)[-2000:]
    return out


@pytest.mark.parametrize(("name", "height"), [("ThinWall.stl", 5.0),
                                              ("CalibrationCube.stl", 20.0)])
def test_slic3r_svg_layers_are_in_mm(slic3r, shared_data, tmp_path, name, height):
    svg = _export_svg(slic3r, shared_data / "stl" / name, tmp_path / "part.svg")
    stack = load_layers(svg)
    zs = [layer.z for layer in stack.layers]
    hs = [layer.height for layer in stack.layers]
    # Slic3r 1.3's defaults: a 0.35 mm first layer, then 0.3 mm; the last slicing plane is at
    # most half a layer below the part's top
    assert zs[0] == pytest.approx(0.35, abs=1e-6)
    assert hs[0] == pytest.approx(0.35, abs=1e-6)
    assert all(h == pytest.approx(0.3, abs=1e-6) for h in hs[1:])
    assert height - 0.3 <= zs[-1] <= height + 0.3
    assert any("10⁻⁶ mm" in w for w in stack.meta["warnings"])


def test_slic3r_svg_analysed_through_the_cli(slic3r, shared_data, tmp_path):
    svg = _export_svg(slic3r, shared_data / "stl" / "ThinWall.stl", tmp_path / "part.svg")
    out = tmp_path / "r.json"
    r = subprocess.run([str(Path(sys.executable).with_name("printability")), "analyze",
                        str(svg), "-n", "circle:d=0.4", "-m", "xy", "--json", str(out)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())
    (nozzle,) = res["nozzles"]
    # the part's volume in mm³ (ThinWall's walls over 5 mm), not in nm-thick layers
    volume = sum(layer["target_area"] * layer["height"] for layer in nozzle["layers"])
    assert volume > 100.0
