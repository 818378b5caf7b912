"""Every file of ../shared/data through ``python -m printability analyze`` (the real entry point).

Each run must exit 0 without a traceback and give plausible numbers: positive target
area, 0 ≤ lost ≤ target, as built + lost = target, the lost area inside its certified
bounds, a small nozzle losing no more than a big one. Key figures of
../shared/data/SOURCES.md are pinned (ThinWall fins, Benchy at z = 20.03, SVG areas).

The default run takes one or a few layers of the big inputs (``--layers``); the whole
files, all 300 slices and the heavy layers run under ``-m slow``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SMALL, BIG = "circle:d=0.4", "circle:d=1"


def run_analyze(tmp_path: Path, src: Path, *args: str, nozzles=(SMALL, BIG),
                timeout: float = 3600) -> dict:
    out = tmp_path / f"{src.stem}.json"
    cmd = [sys.executable, "-m", "printability", "analyze", str(src), "--no-progress",
           "--json", str(out), *args]
    for n in nozzles:
        cmd += ["-n", n]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert all(spec in p.stdout for spec in nozzles)          # the ranking table
    doc = json.loads(out.read_text())
    check_plausible(doc)
    return doc


def check_plausible(doc: dict) -> None:
    assert doc["units"] == "mm"
    by_spec = {n["spec"]: n for n in doc["nozzles"]}
    assert sorted(n["rank"] for n in doc["nozzles"]) == list(range(1, len(by_spec) + 1))
    for n in doc["nozzles"]:
        t, s, lost = n["target_area"], n["as_built_area"], n["lost_area"]
        lo, hi = n["lost_area_bounds"]
        tol = 1e-6 * max(1.0, t)
        assert t > 0
        assert -tol <= lost <= t + tol
        assert s + lost == pytest.approx(t, rel=1e-6, abs=1e-9)
        assert lo - tol <= lost <= hi + tol
        assert 0 <= n["lost_fraction"] <= 1
        assert len(n["layers"]) == doc["layers"]
        for lay in n["layers"]:
            llo, lhi = lay["lost_area_bounds"]
            assert llo - tol <= lay["lost_area"] <= lhi + tol
        if doc["layers"] > 1:
            assert n["lost_volume"] <= n["target_volume"] + tol
    if SMALL in by_spec and BIG in by_spec:
        # an opening by a bigger disc removes at least as much: compare certified bounds
        assert by_spec[SMALL]["lost_area_bounds"][0] <= by_spec[BIG]["lost_area_bounds"][1] + 1e-6


# --- G-code --------------------------------------------------------------------------
# mmc.exact spends minutes on one G-code layer (tens of thousands of vertices from the
# bead union), so the default run takes the top layer of the spiral vase only.

GCODE_SAMPLES = {
    "prusaslicer_2.7.4_spiral_vase.gcode": "-1",
}
GCODE_SLOW = {
    "bambustudio_1.10_klipper_arcs.gcode": "-1",
    "cura_5.9.1_marlin.gcode": "-1",
    "orcaslicer_2.3.0b2_klipper_arcs.gcode": "-1",
    "prusaslicer_2.7.4_marlin2_arcs.gcode": "-1",
    "slic3rpe_1.33_arcwelder_benchy.gcode": "-1",
    "prusaslicer_2.7.4_spiral_vase.gcode": "::40",
}


@pytest.mark.parametrize(("name", "layers"), [
    *GCODE_SAMPLES.items(),
    *(pytest.param(n, lay, marks=pytest.mark.slow) for n, lay in GCODE_SLOW.items()),
])
def test_gcode(shared_data, tmp_path, name, layers):
    doc = run_analyze(tmp_path, shared_data / "gcode" / name, "--layers", layers)
    for n in doc["nozzles"]:
        assert all(lay["z"] > 0 and lay["height"] > 0 for lay in n["layers"])
    small = next(n for n in doc["nozzles"] if n["spec"] == SMALL)
    # the beads of a 0.4 mm nozzle are ~0.4-0.5 mm wide: a 0.4 disc prints most of them
    assert small["lost_fraction"] < 0.5


# --- STL -----------------------------------------------------------------------------

# SOURCES.md: ThinWall section at z = 2.51 is 172.68 mm²; a disc opening of radius r loses
# these areas (shapely buffer, resolution 32, rounded to 0.01 mm²).
THINWALL_LOSS = {0.15: 0.04, 0.2: 4.58, 0.25: 10.99, 0.4: 21.23, 0.5: 33.93}
# Tolerance against those figures: their rounding (0.005) plus the polygonal buffer's
# deviation from true circles (chord error r(1 - cos(pi/64)) ≈ 1.2e-4·r over ~800 mm of
# boundary ≈ 0.05 mm² at most), so 0.06 mm² absolute.
THINWALL_TOL = 0.06


def test_thinwall_fins_vanish_at_the_listed_nozzle_sizes(shared_data, tmp_path):
    # first layer 0.21 then 0.2: layer 12 is cut at its mid-height 0.21 + 11.5·0.2 = 2.51
    nozzles = [f"circle:d={2 * r:g}" for r in THINWALL_LOSS]
    doc = run_analyze(tmp_path, shared_data / "stl" / "ThinWall.stl",
                      "--first-layer-height", "0.21", "--layers", "12", nozzles=nozzles)
    assert doc["selected_layers"] == [12]
    by_spec = {n["spec"]: n for n in doc["nozzles"]}
    for r, ref in THINWALL_LOSS.items():
        n = by_spec[f"circle:d={2 * r:g}"]
        assert n["target_area"] == pytest.approx(172.68, abs=0.01)
        lo, hi = n["lost_area_bounds"]
        assert lo - THINWALL_TOL <= ref <= hi + THINWALL_TOL, (r, ref, lo, hi)
        assert n["lost_area"] == pytest.approx(ref, abs=THINWALL_TOL)
    # ranking follows the nozzle size
    assert [n["spec"] for n in doc["nozzles"]] == nozzles


def test_benchy_at_z_20_03(shared_data, tmp_path):
    # first layer 0.13: layer 100 is cut at 0.13 + 99.5·0.2 = 20.03 mm
    doc = run_analyze(tmp_path, shared_data / "stl" / "3DBenchy_lowpoly.stl",
                      "--first-layer-height", "0.13", "--layers", "100",
                      nozzles=("circle:d=0.4", "circle:d=1"))
    by_spec = {n["spec"]: n for n in doc["nozzles"]}
    # SOURCES.md: 5 parts, 218.22 mm²; 0.41 mm² lost at r = 0.2 and 2.11 at r = 0.5
    for spec, ref in (("circle:d=0.4", 0.41), ("circle:d=1", 2.11)):
        n = by_spec[spec]
        assert n["target_area"] == pytest.approx(218.22, rel=2e-3)
        lo, hi = n["lost_area_bounds"]
        assert lo - 0.01 <= ref <= hi + 0.01
        assert n["components"] == 5


STL_RUNS = [
    ("CalibrationCube.stl", ["--layer-height", "1"]),
    pytest.param("idler_riser_inches.stl", ["--units", "in", "--layer-height", "1"],
                 marks=pytest.mark.slow),
    pytest.param("ThinWall.stl", ["--layer-height", "0.5"], marks=pytest.mark.slow),
    pytest.param("3DBenchy_lowpoly.stl", ["--layer-height", "0.4"], marks=pytest.mark.slow),
    pytest.param("HoleTest.stl", ["--layers", "0,12,-1"], marks=pytest.mark.slow),
    pytest.param("Tolerance.stl", ["--layers", "::20"], marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("name", "args"), STL_RUNS)
def test_stl(shared_data, tmp_path, name, args):
    doc = run_analyze(tmp_path, shared_data / "stl" / name, *args)
    assert doc["layers"] >= 1
    small = next(n for n in doc["nozzles"] if n["spec"] == SMALL)
    assert small["lost_fraction"] < 0.1       # calibration parts are printable with 0.4 mm
    if doc["layers"] > 1:
        assert small["target_volume"] > 0


def test_idler_riser_in_inches_has_mm_size(shared_data, tmp_path):
    doc = run_analyze(tmp_path, shared_data / "stl" / "idler_riser_inches.stl",
                      "--units", "in", "--layer-height", "2", nozzles=(SMALL,))
    n = doc["nozzles"][0]
    # 1.49 in³ = 24,417 mm³; slicing at 2 mm loses or gains a little at the top
    assert n["target_volume"] == pytest.approx(1.49 * 25.4 ** 3, rel=0.1)
    # the bracket is 2.656 × 2.953 in: a 0.4 mm nozzle prints it almost whole
    assert n["lost_fraction"] < 0.01


# --- SVG -----------------------------------------------------------------------------

SVG_AREAS = {  # SOURCES.md, viewBox units (= mm, the default unit of a unit-less SVG)
    "bootstrap_gear-fill.svg": 132.0,
    "bootstrap_bug-fill.svg": 128.4,
    "bootstrap_flower1.svg": 111.6,
    "simpleicons_setuptools.svg": 141.6,
    "simpleicons_gnubash.svg": 149.0,
    "gameicons_lorc_dragon-head.svg": 105_068.0,
}


SVG_DEFAULT = ("bootstrap_gear-fill.svg", "simpleicons_setuptools.svg",
               "gameicons_lorc_dragon-head.svg")


@pytest.mark.parametrize(("name", "area"), [
    (n, a) if n in SVG_DEFAULT else pytest.param(n, a, marks=pytest.mark.slow)
    for n, a in SVG_AREAS.items()])
def test_svg(shared_data, tmp_path, name, area):
    doc = run_analyze(tmp_path, shared_data / "svg" / name)
    for n in doc["nozzles"]:
        assert n["target_area"] == pytest.approx(area, rel=2e-3)


def test_svg_fit_scales_the_area(shared_data, tmp_path):
    # the gear is drawn in a 16-unit box; at --fit 80 its longest side becomes 80 mm
    doc = run_analyze(tmp_path, shared_data / "svg" / "bootstrap_gear-fill.svg", "--fit", "80",
                      nozzles=(SMALL,))
    side = 16.0  # the gear's shape spans the whole 16×16 viewBox
    assert doc["nozzles"][0]["target_area"] == pytest.approx(132.0 * (80 / side) ** 2, rel=0.02)


# --- coastlines ----------------------------------------------------------------------

COASTS = [
    ("japan_110m.geojson", ["--fit", "150"]),
    pytest.param("japan_50m.geojson", ["--fit", "150"], marks=pytest.mark.slow),
    pytest.param("japan_10m.geojson", ["--fit", "150"], marks=pytest.mark.slow),
    pytest.param("greece_10m.geojson", ["--fit", "150"], marks=pytest.mark.slow),
    pytest.param("united_kingdom_10m.geojson", ["--fit", "150"], marks=pytest.mark.slow),
    # mainland only (SOURCES.md): with Svalbard and Bouvet Island in the box, 150 mm spans
    # 135° of latitude and a 0.4 mm nozzle loses 23 % of the country
    pytest.param("norway_10m.geojson", ["--clip", "4,57,32,72", "--fit", "150"],
                 marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("name", "args"), COASTS)
def test_coastline(shared_data, tmp_path, name, args):
    doc = run_analyze(tmp_path, shared_data / name, *args)
    small, big = (next(n for n in doc["nozzles"] if n["spec"] == s) for s in (SMALL, BIG))
    # islands and fjords narrower than the nozzle go: a bigger nozzle loses more
    assert 0 < small["lost_area"] < big["lost_area"]
    assert small["lost_fraction"] < 0.05


# --- slice outlines ------------------------------------------------------------------

def _slices() -> list[str]:
    import os

    root = Path(__file__).resolve().parents[2]
    folder = Path(os.environ.get("PRINTABILITY_SHARED_DATA", root.parent / "shared" / "data"))
    folder = folder / "slices"
    return sorted(p.name for p in folder.glob("*.txt") if p.name != "LICENSE-BSD3.txt") \
        if folder.is_dir() else []


ALL_SLICES = _slices()
SAMPLE_SLICES = ALL_SLICES[::100]   # 3 of 300, spread over the alphabet (different models)


@pytest.mark.parametrize("name", SAMPLE_SLICES or ["<no data>"])
def test_slice_sample(shared_data, tmp_path, name):
    run_analyze(tmp_path, shared_data / "slices" / name)


@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_SLICES or ["<no data>"])
def test_every_slice(shared_data, tmp_path, name):
    run_analyze(tmp_path, shared_data / "slices" / name, nozzles=(SMALL,))
