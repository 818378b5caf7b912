"""Raster MMC engine against OpenCV on Japan, side by side in one run.

The case of issue 2: Japan's main islands (Natural Earth 10m, clipped to lon
128–146, lat 30–46, equirectangular about lat 38°, longest side scaled to
100 mm) at h = 0.04 mm, an ellipse 1.6 × 0.6 mm on a T-T-R machine sampled
every 1° over the nozzle's 180° period (180 angles).

Both sides compute the same three openings per angle on the same rasterised
inputs and kernels (taken from :func:`printability.mmc.raster.prepare_raster`):
inner (P_in = I ⊖ K_touch, S_in = ∪ P_in ⊕ K_full), outer (P_out = (I ∪ C) ⊖
K_need, S_out = ∪ P_out ⊕ K_dil ∩ (I ∪ C)) and estimate (B ⊖ K_c ⊕ K_c).
OpenCV does them with ``cv2.erode`` / ``cv2.dilate`` per angle on uint8
images (union by OR); the check compares every resulting pixel, and the
per-pixel count of feasible angles.

Usage::

    python benchmarks/bench_raster.py [--data PATH] [--angles-step DEG] [--resolution MM]

Prints times, the ratio and peak memory, and the engine with and without its band
settling below the pixel (:mod:`printability.mmc._band`, issue #26; the OpenCV
comparison is of the three passes, on the same pixels either way). Not a test: nothing
is asserted on time; the pixel comparison exits with status 1 on a mismatch.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import shape

from printability.mmc import _raster_kernels as rk
from printability.mmc._raster_passes import opening_pass
from printability.mmc.raster import _erode3, mmc_raster, prepare_raster
from printability.model.geometry import as_region
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "japan_10m.geojson"


def load_japan(path: Path) -> shapely.MultiPolygon:
    """Japan's main islands, projected and scaled so the longest side is 100 mm."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    geom = shape(doc["geometry"] if doc.get("type") == "Feature" else doc)
    geom = shapely.clip_by_rect(geom, 128.0, 30.0, 146.0, 46.0)
    geom = affinity.scale(geom, np.cos(np.radians(38.0)), 1.0, origin=(0, 0))
    minx, miny, maxx, maxy = geom.bounds
    s = 100.0 / max(maxx - minx, maxy - miny)
    geom = affinity.scale(affinity.translate(geom, -minx, -miny), s, s, origin=(0, 0))
    return as_region(geom, name="japan")


def opencv_openings(prob, cv2):
    """The three passes with OpenCV; returns (S_in, S_out, S_est, count) as arrays."""
    cls = prob.cls
    r = prob.radius
    border = {"borderType": cv2.BORDER_CONSTANT, "borderValue": 0, "anchor": (r, r)}
    inside = (cls == 3).astype(np.uint8)
    some = (cls >= 1).astype(np.uint8)
    centre = (cls >= 2).astype(np.uint8)
    count = np.zeros(cls.shape, np.uint16)
    out = []
    for inp, er, di, clip, counting in (
        (inside, prob.touch, prob.full, None, True),
        (some, prob.need, prob.dil, some, False),
        (centre, prob.centre, prob.centre, None, False),
    ):
        union = np.zeros(cls.shape, np.uint8)
        for k in range(len(prob.angles)):
            # cv2.erode reads src(x + x' − anchor): erosion without reflection, as ours;
            # cv2.dilate reads the same way, so S = P ⊕ K needs the reflected kernel.
            p = cv2.erode(inp, er[k].astype(np.uint8), **border)
            if counting:
                count += p
            s = cv2.dilate(p, di[k][::-1, ::-1].astype(np.uint8).copy(), **border)
            np.bitwise_or(union, s, out=union)
        if clip is not None:
            union &= clip
        out.append(union.astype(bool))
    return (*out, count)


def ours_openings(prob):
    """Our three passes alone (the same work as :func:`opencv_openings`)."""
    cls = prob.cls
    nx = prob.grid.nx
    inside = rk.pack_bits(cls == 3)
    core = rk.pack_bits(_erode3(cls == 3))
    some = rk.pack_bits(cls >= 1)
    centre = rk.pack_bits(cls >= 2)
    tick = lambda: None  # noqa: E731
    a = opening_pass(inside, core, prob.touch, prob.full, prob.radius, nx, store=True, tick=tick)
    b = opening_pass(some, some, prob.need, prob.dil, prob.radius, nx, store=False, tick=tick)
    c = opening_pass(centre, centre, prob.centre, prob.centre, prob.radius, nx, store=False,
                     tick=tick)
    return a, b, c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--resolution", type=float, default=0.04)
    ap.add_argument("--angle-step", type=float, default=1.0)
    ap.add_argument("--nozzle", default="ellipse:major=1.6,minor=0.6")
    args = ap.parse_args(argv)
    try:
        import cv2
    except ImportError:
        print("opencv-python-headless is needed for this benchmark (pip install "
              "opencv-python-headless)", file=sys.stderr)
        return 2

    region = load_japan(args.data)
    nozzle = parse_nozzle(args.nozzle)
    machine = parse_machine("ttr")
    settings = Settings(resolution=args.resolution, angle_step=args.angle_step)

    # compile the numba kernels (cached on disk after the first run) outside the timings
    warm = as_region(shapely.box(0, 0, 4, 3))
    mmc_raster(warm, nozzle, machine, settings=settings.with_(resolution=0.1, angle_step=30.0))

    t0 = time.perf_counter()
    res = mmc_raster(region, nozzle, machine, settings=settings)
    t_engine = time.perf_counter() - t0
    # the same without the band settling below the pixel (issue #26): the raster part alone
    t0 = time.perf_counter()
    plain = mmc_raster(region, nozzle, machine, settings=settings, settle_band=False)
    t_plain = time.perf_counter() - t0
    rss_engine = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    # memory in a second, untimed run (tracemalloc slows allocation-heavy code down)
    tracemalloc.start()
    mmc_raster(region, nozzle, machine, settings=settings)
    _, peak_traced = tracemalloc.get_traced_memory()
    tracemalloc.stop()

    t0 = time.perf_counter()
    prob = prepare_raster(region, nozzle, machine, settings=settings)
    t_prepare = time.perf_counter() - t0
    t0 = time.perf_counter()
    inner, outer, est = ours_openings(prob)
    t_ours = time.perf_counter() - t0

    t0 = time.perf_counter()
    cv_in, cv_out, cv_est, cv_count = opencv_openings(prob, cv2)
    t_cv = time.perf_counter() - t0

    g = prob.grid
    nx = g.nx
    checks = {
        "S_inner": np.array_equal(rk.unpack_bits(inner.union, nx), cv_in),
        "S_outer": np.array_equal(rk.unpack_bits(outer.union, nx), cv_out),
        "S_estimate": np.array_equal(rk.unpack_bits(est.union, nx), cv_est),
        "P_inner count": np.array_equal(res.motion.count.data, cv_count),
        "engine S_inner": np.array_equal(res.as_built_raster.data, cv_in),
    }
    n = len(prob.angles)
    print(f"Japan main islands, {region.area:.1f} mm², {len(region.geoms)} polygons; "
          f"grid {g.nx} × {g.ny} at h = {g.h:g} mm; {args.nozzle} on ttr, {n} angles")
    print(f"lost area {res.lost_area:.3f} mm² in [{res.lost_area_bounds[0]:.3f}, "
          f"{res.lost_area_bounds[1]:.3f}] ({100 * res.lost_fraction:.2f} %), "
          f"{res.components.count} components; "
          f"P stored in {res.motion.packed.nbytes / 2**20:.1f} MiB")
    print(f"  without the band settling: [{plain.lost_area_bounds[0]:.3f}, "
          f"{plain.lost_area_bounds[1]:.3f}], estimate {plain.lost_area:.3f} mm²")
    print(f"printability mmc_raster, end to end        {t_engine:8.2f} s")
    print(f"  without the band settling                 {t_plain:8.2f} s")
    print(f"  of which rasterisation + kernels          {t_prepare:8.2f} s")
    print(f"printability openings alone (3 passes)      {t_ours:8.2f} s")
    print(f"OpenCV erode+dilate per angle (3 passes)    {t_cv:8.2f} s   "
          f"({cv2.getNumThreads()} threads, {cv2.__version__})")
    print(f"ratio OpenCV / ours, same openings          {t_cv / t_ours:8.1f} ×")
    print(f"ratio OpenCV openings / ours end to end     {t_cv / t_engine:8.1f} ×")
    print(f"peak memory of mmc_raster: traced {peak_traced / 2**20:.0f} MiB, "
          f"process max RSS {rss_engine / 2**20:.0f} MiB")
    ok = all(checks.values())
    print("same pixels:", ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in checks.items()))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
