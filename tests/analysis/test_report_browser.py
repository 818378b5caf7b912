"""The HTML report opened in a real browser (headless Chromium from Debian's packages).

The report is made by the real entry point; Chromium renders ``index.html`` to a PNG and
the pixels are checked: not blank, and the report's colours (as built, lost, P, the
per-layer plot) are on the page.
"""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (apt-get install chromium; "
    "scripts/system-packages.txt lists it)")

AS_BUILT, LOST, P_GREEN = (0x4C, 0x9B, 0xE8), (0xE8, 0x51, 0x4C), (0x2C, 0xA2, 0x5F)
UNCERTAIN = (0xF0, 0xA0, 0x30)   # G minus a raster engine's certified inner S


def screenshot(page, png, tmp_path):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={tmp_path / 'chromium-profile'}",
           f"--screenshot={png}", "--window-size=1400,2000", page.as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    assert png.is_file() and png.stat().st_size > 0


def share_of(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> float:
    return float(np.mean(np.all(np.abs(img[..., :3].astype(int) - rgb) <= tol, axis=-1)))


@pytest.mark.parametrize(("src", "args", "multi"), [
    # a rotary machine with an elliptical nozzle (P in its parameter space, angle slices)
    # and a round one; four layers, so the per-layer plot is there too
    ("stl/ThinWall.stl", ["--layer-height", "2", "-m", "ttr",
                          "-n", "ellipse:major=0.8,minor=0.3", "-n", "circle:d=0.8"], True),
])
def test_report_renders_in_chromium(shared_data, tmp_path, src, args, multi):
    import matplotlib.image as mpimg

    out = tmp_path / "report"
    p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(shared_data / src),
                        *args, "--no-progress", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    index = out / "index.html"
    assert f"report: {index}" in p.stdout
    png = tmp_path / "shot.png"
    screenshot(index, png, tmp_path)

    img = (mpimg.imread(png) * 255).astype(np.uint8)
    assert img.shape[:2] == (2000, 1400)
    gray = img[..., :3].mean(axis=-1)
    assert gray.std() > 20                               # not a blank page
    assert np.mean(gray < 250) > 0.05                    # ink on more than 5 % of the page
    assert share_of(img, AS_BUILT) > 0.001               # the as-built layer is drawn
    # what is lost (red), or lost-or-uncertain for the raster engine (orange), is drawn
    assert share_of(img, LOST) + share_of(img, UNCERTAIN) > 0.0005
    assert share_of(img, P_GREEN) > 0.001                # P and its angle slices
    # every figure the page names was embedded and written beside it
    page = index.read_text()
    for name in ("nozzle1_layer.png", "nozzle1_motion.png", "nozzle1_components.png",
                 "nozzle2_layer.png"):
        assert name in page and (out / name).stat().st_size > 5000
    assert ("lost_per_layer.png" in page) == multi
    assert page.count("data:image/png;base64,") >= 6
