"""G-code reading speed: our tokeniser and full parse against pygcode and gcodeparser.

Run:  python benchmarks/bench_gcode_reader.py [--repeat N] [--pygcode-lines N]

For each sample file in ../shared/data/gcode, in one run, lines per second of

* ``lex (numba)``     our whole-file tokeniser (gcode._lexer.lex): lines, words, values
* ``parse_gcode``     our full parse: tokeniser + modal state machine (moves, arcs, E modes)
                      + slicer comments (layers, features, widths)
* ``parse_line (py)`` our pure-Python regex tokeniser, one line at a time (the lossless
                      token stream the tests check the numba tables against)
* ``split (py)``      the tightest pure-Python loop we could write: bytes lines,
                      comment cut, ``split()``, ``float()`` per word (a baseline that
                      shows why the tokeniser is compiled)
* ``gcodeparser``     gcodeparser.parse_gcode_lines on the whole file (drops lines it does
                      not understand, such as Klipper macros: lossy)
* ``pygcode``         pygcode.Line per line, on a subsample of ``--pygcode-lines`` evenly
                      spaced lines per file (pygcode runs at ~25 k lines/s; the full files
                      would take most of the time budget). Lines it rejects (``M84 X Y E``,
                      Klipper macros...) are counted and timed like the others.

Times are the best of ``--repeat`` runs (pygcode: one run). The numba kernel is
compiled (or loaded from its cache) before timing; the first-call time is
printed separately. The ratios divide our rate by pygcode's and gcodeparser's.
ArcWelder's C++ parser is quoted at ~200 k lines/s; the goal is ≥ 20× pygcode.
Typical total run time: well under a minute.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT.parent / "shared" / "data" / "gcode"


def best_of(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def split_tokenise(data: bytes) -> int:
    n = 0
    for line in data.splitlines():
        i = line.find(b";")
        if i >= 0:
            line = line[:i]
        parts = line.split()
        if not parts:
            continue
        for w in parts[1:]:
            try:
                float(w[1:])
            except ValueError:
                pass
            n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--pygcode-lines", type=int, default=4000)
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()

    import gcodeparser
    import pygcode

    from gcode import parse_gcode, parse_line
    from gcode._lexer import lex

    files = sorted(args.data.glob("*.gcode"))
    if not files:
        sys.exit(f"no .gcode files in {args.data}")

    t = time.perf_counter()
    lex(b"G1 X1\n")
    parse_gcode(b"G1 X1\n")
    first_call = time.perf_counter() - t

    rows = []
    totals = {k: [0, 0.0] for k in ("lex", "parse", "pyline", "split", "gcp", "pyg")}
    pyg_rejects = 0
    for f in files:
        data = f.read_bytes()
        text = data.decode("utf-8", "replace")
        lines = data.splitlines(keepends=True)
        n = len(lines)
        r = {"file": f.name, "lines": n}
        r["lex"] = best_of(lambda d=data: lex(d), args.repeat)
        r["parse"] = best_of(lambda d=data: parse_gcode(d), args.repeat)
        r["pyline"] = best_of(lambda ls=lines: [parse_line(x) for x in ls], 1)
        r["split"] = best_of(lambda d=data: split_tokenise(d), args.repeat)
        r["gcp"] = best_of(
            lambda s=text: list(gcodeparser.parse_gcode_lines(s, include_comments=True)), 1
        )
        step = max(1, n // args.pygcode_lines)
        sample = [x.decode("utf-8", "replace").rstrip("\r\n") for x in lines[::step]]
        rejects = 0
        t = time.perf_counter()
        for s in sample:
            try:
                pygcode.Line(s)
            except Exception:  # pygcode raises several types on real slicer lines
                rejects += 1
        r["pyg"] = time.perf_counter() - t
        r["pyg_n"] = len(sample)
        pyg_rejects += rejects
        r["pyg_rej"] = rejects
        for k in ("lex", "parse", "pyline", "split", "gcp"):
            totals[k][0] += n
            totals[k][1] += r[k]
        totals["pyg"][0] += len(sample)
        totals["pyg"][1] += r["pyg"]
        rows.append(r)

    def rate(n, t):
        return n / t if t > 0 else float("inf")

    hdr = (
        f"{'file':40s} {'lines':>7s} {'lex(numba)':>11s} {'parse_gcode':>11s} "
        f"{'parse_line':>10s} {'split(py)':>10s} {'gcodeparser':>11s} {'pygcode':>9s} "
        f"{'lex/pyg':>8s} {'parse/pyg':>9s} {'lex/gcp':>8s} {'parse/gcp':>9s}"
    )
    print("lines per second (k = thousand)")
    print(hdr)
    print("-" * len(hdr))

    def fmt(x):
        return f"{x / 1e3:,.0f}k"

    for r in rows:
        n = r["lines"]
        lx, pa = rate(n, r["lex"]), rate(n, r["parse"])
        pg, gp = rate(r["pyg_n"], r["pyg"]), rate(n, r["gcp"])
        print(
            f"{r['file']:40s} {n:7d} {fmt(lx):>11s} {fmt(pa):>11s} "
            f"{fmt(rate(n, r['pyline'])):>10s} {fmt(rate(n, r['split'])):>10s} {fmt(gp):>11s} "
            f"{fmt(pg):>9s} {lx / pg:7.0f}x {pa / pg:8.0f}x {lx / gp:7.0f}x {pa / gp:8.0f}x"
        )
    tot = {k: rate(*v) for k, v in totals.items()}
    n_all = totals["lex"][0]
    print("-" * len(hdr))
    print(
        f"{'all files':40s} {n_all:7d} {fmt(tot['lex']):>11s} {fmt(tot['parse']):>11s} "
        f"{fmt(tot['pyline']):>10s} {fmt(tot['split']):>10s} {fmt(tot['gcp']):>11s} "
        f"{fmt(tot['pyg']):>9s} {tot['lex'] / tot['pyg']:7.0f}x "
        f"{tot['parse'] / tot['pyg']:8.0f}x {tot['lex'] / tot['gcp']:7.0f}x "
        f"{tot['parse'] / tot['gcp']:8.0f}x"
    )
    print()
    print(f"numba first call (compile or load from cache): {first_call:.2f} s")
    print(f"pygcode: {totals['pyg'][0]} sampled lines, {pyg_rejects} rejected by pygcode "
          "(valueless words, Klipper macros, ...)")
    print("goal: lex >= 20x pygcode and > 200k lines/s (ArcWelder's C++ parser)")


if __name__ == "__main__":
    main()
