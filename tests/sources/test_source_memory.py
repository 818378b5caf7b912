"""The memory guard of the drawing and map readers estimates at least what a load uses
(issue #24: a 20 MB WKT layer passed a guard of 40 bytes per byte and used more).

Each load runs in its own process, on a file of many small polygons (the costliest kind per
byte: each is a shapely object, a GEOS geometry and a share of the union); the peak resident
memory the load adds, over the process after its imports, must stay within the reader's
estimate. A memory measure, not a timing one: the allocations are the same on any machine.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

_MEASURE = """
import json, resource, sys
from pathlib import Path
import numpy, shapely
import printability.sources.geo as geo
import printability.sources.slices as slices
from printability.sources import load_layers
def peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
before = peak()
load_layers(sys.argv[1])
module = geo if sys.argv[1].endswith((".wkt", ".geojson")) else slices
print(json.dumps({"added": peak() - before, "factor": module._BYTES_PER_INPUT_BYTE}))
"""


def _squares(n: int) -> list[tuple[float, float]]:
    return [((i % 300) * 0.5, (i // 300) * 0.5) for i in range(n)]


def _write(folder: Path, kind: str, n: int) -> Path:
    corners = ((0, 0), (0.3, 0), (0.3, 0.3), (0, 0.3), (0, 0))
    if kind == "wkt":
        path = folder / "many.wkt"
        path.write_text("".join("POLYGON ((" + ", ".join(f"{x + a:.6f} {y + b:.6f}"
                                                          for a, b in corners) + "))\n"
                                for x, y in _squares(n)))
    elif kind == "geojson":
        path = folder / "many.geojson"
        features = [{"type": "Feature", "properties": {"id": i},
                     "geometry": {"type": "Polygon",
                                  "coordinates": [[[round(x + a, 6), round(y + b, 6)]
                                                   for a, b in corners]]}}
                    for i, (x, y) in enumerate(_squares(n))]
        path.write_text(json.dumps({"type": "FeatureCollection", "features": features,
                                    "crs": {"type": "name",
                                            "properties": {"name": "EPSG:3857"}}}))
    else:
        path = folder / "many_outline.txt"
        path.write_text("0.3\n0.7\n" + "".join(
            "4\n" + "".join(f"{x + a:.3f} {y + b:.3f}\n" for a, b in corners[:4])
            for x, y in _squares(n)))
    return path


@pytest.mark.parametrize(("kind", "n"), [("wkt", 20_000), ("geojson", 8_000),
                                         ("slices", 20_000)])
def test_a_load_stays_within_its_memory_estimate(tmp_path, kind, n):
    path = _write(tmp_path, kind, n)
    r = subprocess.run([sys.executable, "-c", _MEASURE, str(path)], capture_output=True,
                       text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    size = path.stat().st_size
    print(kind, f"{size / 1e6:.1f} MB, {got['added'] / size:.1f} bytes per byte, estimate "
          f"{got['factor']:g}")
    assert got["added"] <= got["factor"] * size
