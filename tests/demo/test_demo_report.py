"""The demo's report says what it measures and shows every nozzle (issue #23).

- the per-layer table, on the page and in the terminal's form, gives each column's unit;
- the ranking is in the unit ``analyze`` ranks by (mm³ for several layers), with bounds;
- the figure shows each candidate nozzle's prediction (the round one's losses too) beside
  what the simulator deposited, holes drawn empty; checked in headless Chromium.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from printability.app.demo import LAYER_COLUMNS, DemoLayer, format_layer_table

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
AS_BUILT, LOST, DEPOSITED = (0x4C, 0x9B, 0xE8), (0xE8, 0x51, 0x4C), (0x7B, 0x32, 0x94)
WHITE = (0xFF, 0xFF, 0xFF)
# a 20 mm square with an 8 mm hole wound like its exterior (a fill by ring painted it)
SQUARE_WITH_HOLE = "POLYGON ((0 0, 20 0, 20 20, 0 20, 0 0), (6 6, 14 6, 14 14, 6 14, 6 6))\n"
ROUND, ELLIPSE = "circle:d=0.8", "ellipse:major=0.8,minor=0.4"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The demo on the square with a hole: the ellipse loses slivers at the outer corners,
    the round nozzle the corners themselves."""
    tmp = tmp_path_factory.mktemp("demo")
    part = tmp / "square.wkt"
    part.write_text(SQUARE_WITH_HOLE)
    out = tmp / "report"
    r = subprocess.run([sys.executable, "-m", "printability", "demo", "--part", str(part),
                        "--out", str(out)], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "MPLBACKEND": "Agg"})
    assert r.returncode == 0, r.stderr
    return out


def test_layer_table_gives_units():
    rows = [DemoLayer(z=0.2, target_area=179.2, predicted_area=179.19, deposited_area=172.66,
                      outside_area=0.0, covered_target=0.964, covered_prediction=0.961)]
    lines = format_layer_table(rows).splitlines()
    assert lines[0].split()[:3] == ["z", "target", "G"]
    assert lines[1].split() == ["(mm)", "(mm²)", "(mm²)", "(mm²)", "(mm²)", "(%)", "(%)"]
    assert lines[2].split() == ["0.20", "179.20", "179.19", "172.66", "0.0000", "96.4", "96.1"]
    # every column's unit is given, the name and unit lines as wide as the numbers
    assert [u for _, u in LAYER_COLUMNS] == ["mm", "mm²", "mm²", "mm²", "mm²", "%", "%"]
    assert len({len(line) for line in lines}) == 1


def test_report_tables_give_units(demo):
    page = (demo / "report.html").read_text()
    doc = json.loads((demo / "report.json").read_text())
    layer_head = re.search(r"<h2>5\..*?<tr>(.*?)</tr>", page, re.S).group(1)
    assert re.findall(r"<th>(.*?)</th>", layer_head) == [f"{n} ({u})" for n, u in LAYER_COLUMNS]
    rank_head = re.search(r"<h2>1–2\..*?<tr>(.*?)</tr>", page, re.S).group(1)
    heads = re.findall(r"<th>(.*?)</th>", rank_head)
    # one layer here: areas, with their bounds in the same unit
    assert heads == ["rank", "nozzle", "lost mm²", "lost %", "bounds mm²"]
    for row in doc["ranking"]:
        lo, hi = row["lost_area_bounds"]
        assert lo <= row["lost_area"] <= hi
        assert f"[{lo:.4g}, {hi:.4g}]" in page


def test_ranking_of_several_layers_in_volumes(tmp_path):
    """The bundled comb (4 layers): the page ranks by volume, as analyze does."""
    from printability.analysis import analyze
    from printability.app.demo import DEMO_PART, DemoResult, _html, _ranking_row
    from printability.sources import load_layers

    a = analyze(load_layers(DEMO_PART, layer_height=0.2), [ROUND], "xy")
    row = _ranking_row(a.nozzles[0])
    assert row["lost_volume"] == pytest.approx(a.nozzles[0].volume("lost_area"))
    assert row["lost_volume_bounds"][0] <= row["lost_volume"] <= row["lost_volume_bounds"][1]

    class Stream:
        acknowledged = total = resends = timeouts = reconnects = 0
        mode, resend_ratio = "send-ahead", 0.0

    res = DemoResult(tmp_path, (), (row,), ROUND, "xy", 0, Stream(), True, (), 0, 0.0)
    heads = re.findall(r"<th>(.*?)</th>", _html(res, figure=False).split("<h2>3.")[0])
    assert heads[2:5] == ["lost mm³", "lost %", "bounds mm³"]
    assert "lost area mm² (Σ layers)" in heads


def mask_of(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> np.ndarray:
    return np.all(np.abs(img[..., :3].astype(int) - rgb) <= tol, axis=-1)


def blobs(mask: np.ndarray, min_px: int = 3000) -> list[tuple[slice, slice]]:
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    sizes = ndimage.sum(mask, labels, range(1, n + 1))
    return sorted((b for b, s in zip(ndimage.find_objects(labels), sizes, strict=True)
                   if s >= min_px), key=lambda b: b[1].start)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install "
                    "chromium; scripts/system-packages.txt lists it)")
def test_figure_shows_every_nozzle_beside_the_deposition(demo, tmp_path):
    import matplotlib.image as mpimg

    png = tmp_path / "shot.png"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'chromium-profile'}",
           f"--screenshot={png}", "--window-size=1400,2400", (demo / "report.html").as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    img = (mpimg.imread(png) * 255).astype(np.uint8)
    doc = json.loads((demo / "report.json").read_text())
    lost = {r["nozzle"]: r["lost_area"] for r in doc["ranking"]}
    # the ellipse, turned, reaches into the square's corners all but a sliver (a shapely
    # opening over 1° steps gives 0.0114 mm²); the round nozzle loses r²(4 − π) there
    assert 0 < lost[ELLIPSE] < 0.1 * lost[ROUND]
    assert lost[ROUND] == pytest.approx(0.4**2 * (4 - np.pi), rel=0.02)

    # one row: the ellipse (printed, ranked first), the round nozzle, the deposition
    predicted = blobs(mask_of(img, AS_BUILT))
    deposited = blobs(mask_of(img, DEPOSITED))
    assert len(predicted) == 2 and len(deposited) == 1, (predicted, deposited)
    panels = [*predicted, *deposited]
    tops = [b[0].start for b in panels]
    assert max(tops) - min(tops) < 20, "the panels are not side by side"
    assert predicted[0][1].stop < predicted[1][1].start < deposited[0][1].start
    red = mask_of(img, LOST)
    for b, spec in zip(predicted, (ELLIPSE, ROUND), strict=True):
        (y0, y1), (x0, x1) = (b[0].start, b[0].stop), (b[1].start, b[1].stop)
        pad = (y1 - y0) // 20
        ys, xs = np.nonzero(red[y0 - pad:y1 + pad, x0 - pad:x1 + pad])
        # red where the numbers say loss a pixel can show, and only there: the round
        # nozzle's four corners (the ellipse's slivers, 0.003 mm² each, are under a pixel)
        assert (len(ys) > 0) == (spec == ROUND), spec
        if len(ys):
            ys, xs = ys + y0 - pad, xs + x0 - pad
            dy = np.minimum(abs(ys - y0), abs(ys - y1)) / (y1 - y0)
            dx = np.minimum(abs(xs - x0), abs(xs - x1)) / (x1 - x0)
            assert np.all(dy + dx < 0.08), "red away from the corners"
    for b in panels:  # the hole is drawn empty in every panel
        c = img[(b[0].start + b[0].stop) // 2, (b[1].start + b[1].stop) // 2, :3].astype(int)
        assert np.all(np.abs(c - WHITE) <= 12), c
    for layer in doc["layers"]:
        assert layer["outside_area"] < 1e-6
