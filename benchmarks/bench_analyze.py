"""Wall time of ``analyze`` on a multi-layer STL with 1, 2, ... worker processes.

Usage: ``python benchmarks/bench_analyze.py [--stl PATH] [--every N] [--workers 1,2]
[--repeat R]``. Loads the mesh once, keeps every N-th layer, then times
:func:`printability.analysis.analyze` (no report) for each worker count, best of R.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from printability.analysis import analyze, select_layers
from printability.settings import Settings
from printability.sources import load_layers

DATA = Path(os.environ.get("PRINTABILITY_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stl", type=Path, default=DATA / "stl" / "3DBenchy_lowpoly.stl")
    ap.add_argument("--every", type=int, default=8, help="keep every N-th layer")
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--nozzle", default="circle:d=0.4")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    stack = select_layers(load_layers(args.stl), f"::{args.every}")
    print(f"{args.stl.name}: {len(stack)} layers, nozzle {args.nozzle}, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    base = None
    for w in (int(v) for v in args.workers.split(",")):
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            analyze(stack, [args.nozzle], "xy", settings=Settings(workers=w), keep_results=False)
            best = min(best, time.perf_counter() - t0)
        base = base or best
        print(f"workers={w}: {best:7.2f} s  (speed-up {base / best:4.2f}x)")


if __name__ == "__main__":
    main()
