"""Benchmark: ``printability generate`` against PrusaSlicer, STL to G-code for the same part.

For each STL of ../shared/data/stl, the real PrusaSlicer (Debian's
``prusa-slicer``) slices it with ``tests/postprocess/data/prusaslicer_ttr.ini``
(0.2 mm layers, 2 perimeters, 15 % infill), and printability generates G-code
for it: the mesh sliced at 0.2 mm (trimesh), 2 walls and infill planned inside
what the nozzle can print, each move at its angle, written through the compiled
emitter. Two nozzles: an ellipse 0.8 × 0.3 on T-T-R (what generate is for: it
plans every orientation) and a round 0.4 mm one on XY (the slicer's own case).

The parts are not the same G-code: the slicer adds skirt, gap fill, top and
bottom skins and sparse infill; generate fills the whole interior at the bead
width (solid infill), so it writes more lines; lines/s is given for both.

Times per part: the slicer's wall and CPU (its process, ``RUSAGE_CHILDREN``;
it uses the machine's cores), ours in a warm process (``load_layers`` +
``generate_gcode``, one thread: CPU = wall), and their ratio. Each figure is
the fastest of the rounds, each round running the slicer and us in turn;
``paired`` is the median over rounds of our CPU over the slicer's in the same
round. A new ``printability generate`` process adds Python's and the
libraries' start, about 2 s whatever the part (see ``bench_postprocess.py``'s
"plugin start").

Run::

    python benchmarks/bench_generate.py            # every STL, 3 rounds (~5 min)
    python benchmarks/bench_generate.py --quick    # the calibration cube and ThinWall

Nothing is asserted: the figures go in the README.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_postprocess import DATA, ELLIPSE, part_names, prusa_slicer, slice_part

NOZZLES = ((ELLIPSE, "ttr"), ("circle:d=0.4", "xy"))


def generate(stl: Path, nozzle: str, machine: str) -> tuple[float, int]:
    """STL to G-code text in this process: (CPU s, lines)."""
    from printability.generate import generate_gcode
    from printability.sources import load_layers

    c0 = time.process_time()
    units = {"units": "in"} if "inches" in stl.name else {}
    layers = load_layers(stl, layer_height=0.2, **units)
    _, res = generate_gcode(layers, nozzle, machine)
    return time.process_time() - c0, res.lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="two small parts only")
    ap.add_argument("--repeat", type=int, default=3, help="rounds (default 3), fastest kept")
    args = ap.parse_args(argv)
    exe = prusa_slicer()
    if exe is None:
        return 1
    names = part_names(quick=args.quick)
    generate(DATA / "CalibrationCube.stl", *NOZZLES[0])  # imports and cached kernels
    print(f"{'part':<24}{'slice s':>9}{'CPU':>7}{'lines':>9}{'lines/s':>10}"
          + "".join(f"{'gen ' + n.split(':')[0] + ' ' + m:>22}{'lines':>9}{'lines/s':>10}"
                    f"{'ratio':>7}{'paired':>8}" for n, m in NOZZLES))
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = Path(tmp) / "sliced.gcode"
            slices, ours = [], {k: [] for k in range(len(NOZZLES))}
            lines = {}
            for _ in range(max(1, args.repeat)):
                slices.append(slice_part(exe, DATA / name, out))
                for k, (nozzle, machine) in enumerate(NOZZLES):
                    cpu, lines[k] = generate(DATA / name, nozzle, machine)
                    ours[k].append(cpu)
            s_wall = min(w for w, _ in slices)
            s_cpu = min(c for _, c in slices)
            s_lines = out.read_bytes().count(b"\n")
            row = f"{name[:23]:<24}{s_wall:>9.2f}{s_cpu:>7.2f}{s_lines:>9}{s_lines / s_cpu:>10.0f}"
            for k in range(len(NOZZLES)):
                best = min(ours[k])
                paired = statistics.median(o / s[1] for o, s in zip(ours[k], slices, strict=True))
                row += (f"{best:>22.2f}{lines[k]:>9}{lines[k] / best:>10.0f}"
                        f"{best / s_cpu:>7.2f}{paired:>8.2f}")
            print(row, flush=True)
    print("ratio = our CPU (one thread) / the slicer's CPU for the same STL; paired = the "
          "median over rounds of the same ratio within a round; lines/s = lines written per "
          "CPU second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
