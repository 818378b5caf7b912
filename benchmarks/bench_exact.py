"""Benchmark: the exact MMC engine against shapely's plain ``buffer(-r).buffer(r)``.

Side by side in one run, on real data (../shared/data): Japan's four main
islands scaled to 100 mm and a few real print slices, for a round nozzle on
XY. For each case it prints the wall time of both (best of ``--repeat``),
their ratio, the lost area of each, our certified bounds [lo, hi], and the
area the plain opening puts *outside* the part (GEOS replaces arcs by chords
and fills shallow dents before offsetting, so a plain opening leaks past
reflex corners; ours never does and is conservative: its lost area is the
upper bound). Then it times an ellipse 1.6 × 0.6 mm on a T-T-R machine with
90 sampled angles (step 2° over the ellipse's 180° period).

Run::

    python benchmarks/bench_exact.py               # Japan + slices, T-T-R on 3 slices
    python benchmarks/bench_exact.py --quick       # one radius, T-T-R on one slice
    python benchmarks/bench_exact.py --japan-ttr   # adds T-T-R on Japan (long)

Nothing here is asserted: the figures go in the README.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import shapely

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "mmc"))
from shapes import SHARED_DATA, load_coastline, load_slice

from printability.mmc.exact import mmc_exact
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings

SLICES = (
    "jet-engine-Fan---Cut-1-of-3-With-Supports_outline_mesh0_z19700.txt",
    "pocket-operator-Lid-Robot_outline_mesh0_z2100.txt",
    "david-scaled_outline_mesh0_z14100.txt",
)


def best_of(fn, repeat: int):
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def circle_case(name: str, g, r: float, repeat: int, quad_segs: int) -> None:
    settings = Settings(quad_segs=quad_segs)
    noz, mach = parse_nozzle(f"circle:r={r}"), parse_machine("xy")
    t_ours, res = best_of(lambda: mmc_exact(g, noz, mach, settings=settings), repeat)
    t_plain, s_plain = best_of(
        lambda: shapely.buffer(shapely.buffer(g, -r, quad_segs=quad_segs), r,
                               quad_segs=quad_segs), repeat)
    lost_plain = g.area - shapely.intersection(s_plain, g).area
    leak = shapely.difference(s_plain, g).area
    lo, hi = res.lost_area_bounds
    inside = "yes" if lo <= lost_plain <= hi else "NO"
    print(f"{name:<28} {r:5.2f} {len(shapely.get_coordinates(g)):7d} {t_ours:8.3f} "
          f"{t_plain:8.4f} {t_ours / t_plain:7.1f}x {res.lost_area:10.4f} {lost_plain:10.4f} "
          f"[{lo:9.4f}, {hi:9.4f}] {inside:>4} {leak:10.2e} {res.as_built.difference(g).area:8.1e}")


def ttr_case(name: str, g, angles: int) -> None:
    noz, mach = parse_nozzle("ellipse:major=1.6,minor=0.6"), parse_machine("ttr")
    settings = Settings(angle_step=180.0 / angles)
    t0 = time.perf_counter()
    res = mmc_exact(g, noz, mach, settings=settings)
    dt = time.perf_counter() - t0
    lo, hi = res.lost_area_bounds
    print(f"{name:<28} {len(res.motion.angles):4d} angles {dt:8.2f} s "
          f"({dt / len(res.motion.angles) * 1e3:6.1f} ms/angle)  lost {res.lost_area:9.4f} mm² "
          f"of {res.target_area:9.2f}, bounds [{lo:.4f}, {hi:.4f}], "
          f"{res.components.count} components")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timing repeats (best of)")
    ap.add_argument("--quad-segs", type=int, default=32, help="chords per quarter circle")
    ap.add_argument("--quick", action="store_true", help="fewer cases")
    ap.add_argument("--japan-ttr", action="store_true",
                    help="also the T-T-R ellipse on Japan (90 angles: minutes)")
    args = ap.parse_args(argv)
    if not SHARED_DATA.is_dir():
        print(f"real data not found at {SHARED_DATA}", file=sys.stderr)
        return 1
    japan = load_coastline("japan_10m", size=100.0)
    slices = {f.split("_outline")[0][:28]: load_slice(SHARED_DATA / "slices" / f)[0]
              for f in SLICES}
    radii = (0.3,) if args.quick else (0.2, 0.3, 0.5)
    print(f"circle on XY, quad_segs={args.quad_segs}; times in s (best of {args.repeat})")
    print(f"{'case':<28} {'r mm':>5} {'verts':>7} {'ours s':>8} {'plain s':>8} {'ratio':>8} "
          f"{'ours lost':>10} {'plain lost':>10} {'our bounds [lo, hi] mm²':>23} {'in?':>4} "
          f"{'plain leak':>10} {'our leak':>8}")
    for r in radii:
        circle_case("japan_10m (100 mm)", japan, r, args.repeat, args.quad_segs)
    for name, g in slices.items():
        circle_case(name, g, 0.2, args.repeat, args.quad_segs)
    print("\nellipse 1.6 × 0.6 mm on T-T-R (90 angles = 2° over the 180° period)")
    for name, g in list(slices.items())[: 1 if args.quick else 3]:
        ttr_case(name, g, 90)
    if args.japan_ttr:
        ttr_case("japan_10m (100 mm)", japan, 90)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
