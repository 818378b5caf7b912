"""Certified bounds at default settings against an independent oracle (issue #26).

For the issue's cases (a star of about 150 mm² with sharp tips, a country outline fit to
100 mm, SVG glyphs fit to 20 mm) and nozzles (an ellipse 0.9 × 0.35 and a circle 0.4 on
T-T-R), the raster engine at its defaults, once without the band settling
(``settle_band=False``, the engine before issue #26's work) and once with it, against an
oracle that shares no code with the engines: the affine ellipse trick with plain shapely
buffers, the union over 1° steps (:func:`shapes.ellipse_opening_loss` of
``tests/mmc/shapes.py``).

It prints, per case: the oracle, each run's estimate and its error, its certified
interval, the interval's width as a share of the loss and of the part, whether it holds the
oracle (within the oracle's chord allowance), and the CPU time. The goal of issue #26: the
estimate within 1 % and hi − lo ≤ 5 % of the loss (or 0.05 % of the part, whichever is
larger), the oracle always inside.

Usage::

    python benchmarks/bench_bounds.py [--quick] [--cases star,japan_50m,...]

Not a test: nothing is asserted; the exit status is 1 when an interval misses the oracle.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "mmc"))

from shapes import ellipse_opening_loss, star  # noqa: E402

from printability.mmc.raster import mmc_raster  # noqa: E402
from printability.model.geometry import as_region  # noqa: E402
from printability.model.machine import parse_machine  # noqa: E402
from printability.model.nozzle import parse_nozzle  # noqa: E402
from printability.settings import Settings  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
CASES = {
    "star": "a 34-point star, 151 mm², tips 10 mm out (sharp: they are lost)",
    "japan_50m": "Japan (Natural Earth 1:50m) fit to 100 mm, 693 mm²",
    "japan_10m": "Japan (Natural Earth 1:10m) fit to 100 mm, 479 mm², 109 islands",
    "svg:bootstrap_bug-fill": "a glyph (Bootstrap bug) fit to 20 mm",
    "svg:gameicons_lorc_dragon-head": "a glyph (dragon head) fit to 20 mm",
}
NOZZLES = ("ellipse:major=0.9,minor=0.35", "circle:d=0.4")


def load(name: str):
    from printability.sources import load_layers

    if name == "star":
        return as_region(star(34, 10.0, 4.8))
    if name.startswith("svg:"):
        return load_layers(DATA / "svg" / f"{name[4:]}.svg", fit=20)[0].region
    return load_layers(DATA / f"{name}.geojson", fit=100)[0].region


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the star and one glyph only")
    ap.add_argument("--cases", default=None, help="comma-separated: " + ", ".join(CASES))
    args = ap.parse_args(argv)
    names = (args.cases.split(",") if args.cases else
             ["star", "svg:bootstrap_bug-fill"] if args.quick else list(CASES))
    machine = parse_machine("ttr")
    settings = Settings()
    # compile the numba kernels (cached on disk after the first run) outside the timings
    for spec in NOZZLES:
        mmc_raster(as_region(shapely.box(0, 0, 4, 3)), parse_nozzle(spec), machine,
                   settings=settings.with_(resolution=0.1))
    missed = 0
    print(f"raster engine at defaults (h = {settings.resolution:g} mm, the machine's "
          f"{machine.angle_step:g}° step) against the shapely oracle (1° steps)")
    for name in names:
        g = load(name)
        print(f"\n{name}: {CASES.get(name, '')}; {g.area:.1f} mm², boundary "
              f"{g.length:.0f} mm, {shapely.get_num_coordinates(g)} vertices")
        for spec in NOZZLES:
            noz = parse_nozzle(spec)
            f = noz.footprints[0]
            angles = np.arange(0.0, 180.0, 1.0) if f.a != f.b else np.array([0.0])
            t = time.process_time()
            oracle, tol = ellipse_opening_loss(g, f.a, f.b, angles)
            t_oracle = time.process_time() - t
            print(f"  {spec}: oracle {oracle:.5g} mm² ({100 * oracle / g.area:.3f} %, "
                  f"{t_oracle:.1f} s CPU)")
            for label, settle in (("before", False), ("after", True)):
                t = time.process_time()
                r = mmc_raster(g, noz, machine, settings=settings, settle_band=settle)
                cpu = time.process_time() - t
                lo, hi = r.lost_area_bounds
                inside = lo - tol <= oracle <= hi + tol
                missed += not inside
                err = 100 * (r.lost_area / oracle - 1) if oracle > 0 else float("nan")
                share = 100 * (hi - lo) / oracle if oracle > 0 else float("inf")
                goal = hi - lo <= max(0.05 * oracle, 5e-4 * g.area)
                print(f"    {label:6s} estimate {r.lost_area:10.5g} ({err:+7.2f} %)  "
                      f"[{lo:.5g}, {hi:.5g}]  width {hi - lo:.4g} = {share:6.1f} % of the "
                      f"loss, {100 * (hi - lo) / g.area:.3f} % of the part"
                      f"{' (goal met)' if goal else ''}; holds the oracle: "
                      f"{'yes' if inside else 'NO'}; {cpu:.2f} s CPU")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
