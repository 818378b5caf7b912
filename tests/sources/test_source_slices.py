"""Slice-outline text files: all 300 shared slices, nesting checked against winding numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from printability.errors import FileFormatError
from printability.sources._common import fill_rings
from printability.sources.slices import load_slice_layers
from tests.conftest import SHARED_DATA

SLICES = sorted(p.name for p in (SHARED_DATA / "slices").glob("*.txt")
                if p.name != "LICENSE-BSD3.txt") if SHARED_DATA.is_dir() else []


def _raw_curves(path: Path) -> list[np.ndarray]:
    lines = path.read_text().split("\n")
    out, i = [], 2
    while i < len(lines) and lines[i].strip():
        n = int(lines[i])
        out.append(np.array([ln.split() for ln in lines[i + 1 : i + 1 + n]], dtype=float))
        i += n + 1
    return out


@pytest.mark.parametrize("name", SLICES)
def test_every_shared_slice_loads(shared_data: Path, name: str):
    stack = load_slice_layers(shared_data / "slices" / name)
    layer = stack[0]
    assert stack.is_planar and layer.region.is_valid
    assert (stack.meta["min_bead_width"], stack.meta["max_bead_width"]) == (0.3, 0.7)
    # Plausible print layers: between a few mm² and ~1 dm², inside a 1 m bed.
    assert 5.0 < layer.area < 20_000.0
    minx, miny, maxx, maxy = layer.region.bounds
    assert max(maxx - minx, maxy - miny) < 1000.0
    assert stack.meta["name_z_um"] > 0


@pytest.mark.parametrize("name", SLICES[::15])
def test_nesting_matches_even_odd_winding(shared_data: Path, name: str):
    # Independent oracle: the even-odd arrangement of the raw curves.
    path = shared_data / "slices" / name
    region = load_slice_layers(path)[0].region
    oracle = fill_rings(_raw_curves(path), "evenodd")
    assert region.symmetric_difference(oracle).area < 1e-6 * region.area


def test_dataset_has_300_slices(shared_data: Path):
    assert len(SLICES) == 300


def test_units_and_fit(tmp_path: Path):
    path = tmp_path / "sq.txt"
    ring = "\n".join(["4", "0 0", "10 0", "10 10", "0 10"])
    hole = "\n".join(["4", "2 2", "4 2", "4 4", "2 4"])
    island = "\n".join(["3", "2.5 2.5", "3.5 2.5", "3 3.5"])
    path.write_text(f"0.4\n0.8\n{ring}\n{hole}\n{island}\n")
    stack = load_slice_layers(path)
    assert stack[0].area == pytest.approx(100 - 4 + 0.5)
    assert stack.meta["curves"] == 3
    scaled = load_slice_layers(path, units="cm")
    assert scaled[0].area == pytest.approx((100 - 4 + 0.5) * 100)
    assert scaled.meta["min_bead_width"] == pytest.approx(4.0)
    fitted = load_slice_layers(path, fit=50.0)
    assert fitted[0].region.bounds == pytest.approx((0, 0, 50, 50))
    assert fitted.meta["max_bead_width"] == pytest.approx(4.0)


@pytest.mark.parametrize(("text", "match"), [
    ("0.3\n", r"expected the minimal and maximal bead widths on lines 1 and 2"),
    ("abc\n0.7\n3\n0 0\n1 0\n0 1\n", r"line 1: expected the minimal bead width"),
    ("0.7\n0.3\n3\n0 0\n1 0\n0 1\n", r"line 2: expected 0 < minimal"),
    ("0.3\n0.7\n5\n0 0\n1 0\n0 1\n", r"line 3: the curve announces 5 points but the file "
                                      r"ends after 3 \(truncated\?\)"),
    ("0.3\n0.7\n3\n0 0\n1 zero\n0 1\n", r"line 5: expected a point 'x y'"),
    ("0.3\n0.7\n3\n0 0\n1 0 0\n0 1\n", r"line 5: expected a point 'x y'"),
    ("0.3\n0.7\nthree\n", r"line 3: expected a point count"),
    ("0.3\n0.7\n3\n0 0\n1 1\n2 2\n", r"no closed curve with positive area"),
    ("0.3\n0.7\n3\n0 0\n1 0\n0 nan\n", r"line 6: expected finite coordinates"),
], ids=["one-line", "bad-width", "widths-swapped", "truncated", "bad-number", "three-numbers",
        "bad-count", "no-area", "nan"])
def test_malformed(tmp_path: Path, text: str, match: str):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=r"bad\.txt(, |: )" + match):
        load_slice_layers(path)


def test_binary_junk(tmp_path: Path):
    path = tmp_path / "junk.txt"
    path.write_bytes(b"0.3\n0.7\n" + bytes(range(128, 256)))
    with pytest.raises(FileFormatError, match=r"junk\.txt, line 3: expected plain ASCII"):
        load_slice_layers(path)
