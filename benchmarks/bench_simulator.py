"""The virtual printer on real slicer files: parser speed, firmware throughput, deposition,
print-time estimate against the slicer's own, and a real host over the pty.

For every file in ``../shared/data/gcode``:

- **parse**: pygcode's word reader (what the firmware uses) on every command line, against
  the firmware's whole parse (pygcode + fallbacks + cache), in lines/s;
- **firmware**: the whole file fed as one byte stream (a streaming host without line
  numbers; Klipper profile for Klipper files) under the simulated clock: lines/s through
  the receive ring, queue, planner and deposition, then the time to union the layers;
- **time**: the simulator's motion time and its clock (motion + heating + dwells) against
  the slicer's estimate, as ratios;
- **printcore**: Printrun's printcore streaming the first 3000 lines over the pty (ping-pong
  with line numbers and checksums), lines/s.

Usage::

    python benchmarks/bench_simulator.py [--data PATH] [--files GLOB] [--no-printcore]

Prints a table; nothing is asserted (not a test).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

from pygcode.exceptions import GCodeWordStrError
from pygcode.words import text2words

from simulators import Firmware, Link, PtyServer, make_config
from simulators import parsing as sim_parsing

_EST = re.compile(r"estimated printing time \(normal mode\) = (.*)$|^;TIME:(\d+)", re.M)


def slicer_estimate(text: str) -> float | None:
    m = _EST.search(text)
    if not m:
        return None
    if m.group(2):
        return float(m.group(2))
    total = 0.0
    for num, unit in re.findall(r"(\d+)([dhms])", m.group(1)):
        total += int(num) * {"d": 86400, "h": 3600, "m": 60, "s": 1}[unit]
    return total


def commands(text: str) -> list[str]:
    out = []
    for line in text.splitlines():
        c = line.split(";", 1)[0].strip()
        if c:
            out.append(c)
    return out


def bench_parse(cmds: list[str]) -> tuple[float, float, int]:
    t = time.perf_counter()
    fails = 0
    for c in cmds:
        try:
            list(text2words(c))
        except GCodeWordStrError:
            fails += 1
    pyg = len(cmds) / (time.perf_counter() - t)
    sim_parsing._cache.clear()
    t = time.perf_counter()
    for c in cmds:
        sim_parsing.parse_command(c)
    full = len(cmds) / (time.perf_counter() - t)
    return pyg, full, fails


def bench_firmware(text: str, profile: str) -> dict[str, float]:
    # A T-T-R machine without bed limits: the files' printers have beds of every size.
    fw = Firmware(make_config(profile=profile, machine="ttr:min=-180,max=180",
                              nozzle="circle:d=0.4"))
    fw.connect()
    # Several files heat through slicer macros the simulator cannot expand (START_PRINT...):
    # allow cold extrusion so every file deposits.
    data = b"M302 P1\n" + text.encode("utf-8", "replace")
    t = time.perf_counter()
    fw.receive(data)
    fw.run_sim()
    fw.drain()
    run = time.perf_counter() - t
    t = time.perf_counter()
    rec = fw.record()
    union = time.perf_counter() - t
    return {"lines": fw.stats.lines_in, "run": run, "union": union, "layers": len(rec.layers),
            "motion": fw.stats.motion_time, "clock": fw.now, "unknown": fw.stats.unknown,
            "area": sum(lr.area for lr in rec.layers),
            "refused": fw.stats.refused_moves}


def bench_printcore(path: Path, n: int = 3000) -> float | None:
    try:
        from printrun import gcoder
        from printrun.printcore import printcore
    except ImportError:
        return None
    lines = path.read_text(errors="replace").splitlines()[:n]
    link = Link(make_config(profile="marlin", clock="sim"))
    with PtyServer(link) as srv:
        p = printcore()
        p.connect(srv.path, 115200)
        while not p.online:
            time.sleep(0.01)
        t = time.perf_counter()
        p.startprint(gcoder.LightGCode(lines))
        while p.printing:
            time.sleep(0.01)
        dt = time.perf_counter() - t
        p.disconnect()
    sent = sum(1 for n_, _ in link.firmware.executed if n_ is not None and n_ >= 0)
    return sent / dt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path,
                    default=Path(__file__).resolve().parents[2] / "shared" / "data" / "gcode")
    ap.add_argument("--files", default="*.gcode")
    ap.add_argument("--no-printcore", action="store_true")
    args = ap.parse_args(argv)
    files = sorted(args.data.glob(args.files))
    if not files:
        print(f"no G-code files in {args.data}", file=sys.stderr)
        return 1
    print(f"{'file':42} {'lines':>6} {'pygcode/s':>10} {'fw parse/s':>10} {'fw lines/s':>10} "
          f"{'union s':>8} {'layers':>6} {'motion s':>9} {'clock s':>8} {'slicer s':>8} "
          f"{'clock/slicer':>12}")
    for path in files:
        text = path.read_text(encoding="utf-8", errors="replace")
        cmds = commands(text)
        pyg, full, _ = bench_parse(cmds)
        profile = "klipper" if "klipper" in path.name else "marlin"
        r = bench_firmware(text, profile)
        est = slicer_estimate(text)
        ratio = f"{r['clock'] / est:.3f}" if est else "-"
        print(f"{path.name:42} {r['lines']:6d} {pyg:10.0f} {full:10.0f} "
              f"{r['lines'] / r['run']:10.0f} {r['union']:8.2f} {r['layers']:6d} "
              f"{r['motion']:9.0f} {r['clock']:8.0f} {est or 0:8.0f} {ratio:>12}")
    if not args.no_printcore:
        # A Marlin file: Klipper files hold lines longer than Marlin's MAX_CMD_SIZE.
        pc = next((f for f in files if "marlin" in f.name), files[0])
        rate = bench_printcore(pc)
        print(f"printcore over the pty ({pc.name}, 3000 lines): "
              + (f"{rate:.0f} lines/s" if rate else "printrun not installed"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
