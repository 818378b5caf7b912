"""Benchmark: post-processing binary G-code against the same G-code as text (issue #28).

PrusaSlicer ≥ 2.7 writes binary G-code (``.bgcode``: Heatshrink 12/4, MeatPack keeping
comments) for Prusa printers; a user who exports text instead hands us the same G-code as
text. For each part, the text G-code (the shared PrusaSlicer 2.7.4 samples, and the shared
STLs sliced by Debian's PrusaSlicer 2.5 with ``tests/postprocess/data/prusaslicer_ttr.ini``
when ``prusa-slicer`` is installed) is made binary by libbgcode with PrusaSlicer's settings
and two thumbnails; then ``printability.postprocess.postprocess_bytes`` rewrites each form
for an elliptical nozzle on a T-T-R machine, the two side by side in each round. Printed per
part: the fastest text and binary times, their ratio (the goal: at most 1.10), the median of
the ratios paired round by round, and what the binary codec itself costs (decoding the file,
encoding the rewritten G-code back: ``gcode.bgcode``).

Run::

    python benchmarks/bench_bgcode.py              # every part, 5 rounds
    python benchmarks/bench_bgcode.py --quick      # the two shared samples, 3 rounds
    python benchmarks/bench_bgcode.py --repeat 9   # more rounds (less noise)

Nothing here is asserted: the figures go in the README.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
CONFIG = ROOT / "tests" / "postprocess" / "data" / "prusaslicer_ttr.ini"
ELLIPSE = "ellipse:major=0.8,minor=0.3"
SAMPLES = ("prusaslicer_2.7.4_marlin2_arcs.gcode", "prusaslicer_2.7.4_spiral_vase.gcode")

sys.path.insert(0, str(ROOT / "tests" / "bgcode"))
from bg_helpers import PRUSA_DEFAULT, binarize, with_thumbnails  # noqa: E402


def parts(*, quick: bool) -> list[tuple[str, bytes]]:
    """(name, text G-code) of every part measured."""
    out = [(name, (DATA / "gcode" / name).read_bytes()) for name in SAMPLES]
    exe = shutil.which("prusa-slicer")
    if quick:
        return out
    if exe is None:
        print("prusa-slicer is not installed (apt-get install prusa-slicer): the shared "
              "samples only", file=sys.stderr)
        return out
    with tempfile.TemporaryDirectory() as tmp:
        for stl in sorted((DATA / "stl").glob("*.stl")):
            gcode = Path(tmp) / (stl.stem + ".gcode")
            subprocess.run([exe, "--export-gcode", "--load", str(CONFIG), "--center",
                            "110,110", "-o", str(gcode), str(stl)], check=True,
                           capture_output=True)
            out.append((stl.name, gcode.read_bytes()))
    return out


def timed(data: bytes, workers: int | None) -> float:
    """Wall seconds of one ``postprocess_bytes`` of ``data``."""
    from printability.postprocess import PostprocessOptions, postprocess_bytes

    options = PostprocessOptions(nozzle=ELLIPSE, machine="ttr", workers=workers)
    t0 = time.perf_counter()
    postprocess_bytes(data, options=options)
    return time.perf_counter() - t0


def codec(binary: bytes, workers: int | None) -> tuple[float, float]:
    """Seconds to decode ``binary`` and to encode its post-processed G-code back."""
    from gcode.bgcode import decode_bgcode, encode_bgcode
    from printability.postprocess import PostprocessOptions, postprocess_bytes

    t0 = time.perf_counter()
    doc = decode_bgcode(binary)
    t_dec = time.perf_counter() - t0
    trailer = doc.trailer()
    out, _ = postprocess_bytes(doc.gcode + trailer, options=PostprocessOptions(
        nozzle=ELLIPSE, machine="ttr", workers=workers))
    t0 = time.perf_counter()
    encode_bgcode(doc, out[:len(out) - len(trailer)])
    return t_dec, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the two shared samples, 3 rounds")
    ap.add_argument("--repeat", type=int, default=None,
                    help="rounds per part, the fastest kept (default 5; --quick 3)")
    ap.add_argument("--workers", "-j", type=int, default=0,
                    help="threads of the post-processor (0: its default, one per core, "
                         "at most 4)")
    args = ap.parse_args(argv)
    rounds = args.repeat or (3 if args.quick else 5)
    workers = args.workers or None
    todo = [(name, text, binarize(with_thumbnails(text), *PRUSA_DEFAULT))
            for name, text in parts(quick=args.quick)]
    timed(todo[0][1], workers)  # warm-up: the compiled kernels load once per process
    timed(todo[0][2], workers)
    print(f"{'part':<40} {'text MB':>7} {'bgcode MB':>9} {'text s':>7} {'binary s':>8} "
          f"{'ratio':>6} {'paired':>6} {'decode s':>8} {'encode s':>8}")
    all_ratios = []
    for name, text, binary in todo:
        t_text, t_bin = [], []
        for _ in range(rounds):
            t_text.append(timed(text, workers))
            t_bin.append(timed(binary, workers))
        dec, enc = codec(binary, workers)
        ratio = min(t_bin) / min(t_text)
        paired = statistics.median(b / t for b, t in zip(t_bin, t_text, strict=True))
        all_ratios.append(ratio)
        print(f"{name:<40} {len(text) / 1e6:7.2f} {len(binary) / 1e6:9.2f} {min(t_text):7.3f} "
              f"{min(t_bin):8.3f} {ratio:6.3f} {paired:6.3f} {dec:8.4f} {enc:8.4f}")
    print(f"binary / text, fastest of {rounds} rounds: median {statistics.median(all_ratios):.3f}"
          f", worst {max(all_ratios):.3f} (goal: at most 1.10)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
