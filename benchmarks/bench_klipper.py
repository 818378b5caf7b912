"""Print time on the real Klipper planner: the slicer's file against what printability makes of it.

What a machine owner meets first is not our CPU time but how long the printer takes. For each
of the six shared STLs (sliced by the real PrusaSlicer with ``tests/postprocess/data/
prusaslicer_ttr.ini``) and each shared slicer sample, side by side in one run:

- **slicer**: the slicer's own file, through klippy in batch mode (its parser, look-ahead
  planner and kinematics; :mod:`simulators.klipper_batch`);
- **post-processed**: the same file after ``postprocess`` for ``ellipse:major=0.8,minor=0.3`` on
  the bundled ``ttr-klipper`` machine (C axis 360 °/s, 3600 °/s², corner velocity 30 °/s), the
  file registering its own axis;
- **faster axis** (estimate): the same post-processing for the same machine with a rotary
  axis twice as fast and four times as strong (720 °/s, 15 000 °/s²), timed by
  :mod:`gcode.printtime` (Klipper's look-ahead, within 0.4 % of klippy on these files): how
  much of the cost is the axis's limits, which the machine's owner sets in the profile;
- **axis unlimited** (estimate): the post-processed file timed by :mod:`gcode.printtime` with
  the rotary axis's speed, acceleration and corner velocity unlimited (a rotation-only move
  still stops the XY motion, as Klipper stops at every move with no XYZ motion): what the
  plan's own path costs, apart from the axis;
- **generated** (STLs only): ``generate`` of the same STL for the same nozzle and machine
  (it fills the interior solid, so it extrudes more than the slicer's 15 % infill: a different
  part, listed for the record).

Times exclude homing (batch mode has no endstop: G28 travels 1.5x each axis). The goal (issue
22) is post-processed <= 1.1x the slicer's. Usage: ``python benchmarks/bench_klipper.py
[--quick]`` (``--quick``: the cube and one sample).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcode import parse_gcode  # noqa: E402
from gcode.printtime import estimate_print_time  # noqa: E402
from printability.generate import generate_file  # noqa: E402
from printability.model.machine import parse_machine  # noqa: E402
from printability.postprocess import PostprocessOptions, postprocess_bytes  # noqa: E402
from simulators.klipper_batch import (  # noqa: E402
    START_END_MACROS,
    klipper_available,
    printer_cfg,
    run_klipper,
)

SHARED = ROOT.parent / "shared" / "data"
CONFIG = ROOT / "tests" / "postprocess" / "data" / "prusaslicer_ttr.ini"
NOZZLE = "ellipse:major=0.8,minor=0.3"
MACHINE = "ttr-klipper"
STLS = ["CalibrationCube.stl", "ThinWall.stl", "3DBenchy_lowpoly.stl", "HoleTest.stl",
        "Tolerance.stl", "idler_riser_inches.stl"]
SAMPLES = ["prusaslicer_2.7.4_marlin2_arcs.gcode", "bambustudio_1.10_klipper_arcs.gcode",
           "orcaslicer_2.3.0b2_klipper_arcs.gcode", "cura_5.9.1_marlin.gcode",
           "slic3rpe_1.33_arcwelder_benchy.gcode"]


def _cfg() -> str:
    m = parse_machine(MACHINE)
    a = m.rotary_axis
    # a bed wide enough for the samples, which were sliced for other printers
    return printer_cfg(bed=(-50.0, 350.0, -50.0, 350.0), z_max=400.0,
                       rotary_velocity=a.max_speed, rotary_accel=a.acceleration,
                       rotary_corner_velocity=a.corner_velocity, extra=START_END_MACROS)


def _time(data: bytes, cfg: str, *, register: bool | None = None) -> tuple[float, object]:
    run = run_klipper(data, cfg=cfg, register_axes=register)
    return run.print_time - run.homing_time, run


def _stops(run) -> int:
    m = run.moves
    return int(((m["start_v"] < 1e-9) & m["kinematic"]).sum())


def _rotation_only(run) -> tuple[int, float]:
    m = run.moves
    c = m["rotary"]
    d = np.r_[0.0, np.diff(np.where(np.isfinite(c), c, 0.0))]
    sel = ~m["kinematic"] & (d != 0)
    return int(sel.sum()), float(m["duration"][sel].sum())


FAST = (720.0, 15000.0)  # °/s, °/s²: the "faster axis" column


def _fast_profile(tmp: Path) -> Path:
    """The bundled ttr-klipper profile with the rotary axis of :data:`FAST`."""
    text = (ROOT / "printability" / "data" / "machines" / f"{MACHINE}.toml").read_text()
    a = parse_machine(MACHINE).rotary_axis
    for key, old, new in (("max_speed", a.max_speed, FAST[0]),
                          ("acceleration", a.acceleration, FAST[1]),
                          ("max_feed_rotary", a.max_speed, FAST[0]),
                          ("rotary_acceleration", a.acceleration, FAST[1])):
        text = text.replace(f"\n{key} = {old}", f"\n{key} = {new}")
    path = tmp / "ttr-klipper-fast.toml"
    path.write_text(text)
    assert parse_machine(str(path)).rotary_axis.max_speed == FAST[0]
    return path


def _row(name: str, before: bytes, cfg: str, tmp: Path, stl: Path | None) -> dict:
    t0, r0 = _time(before, cfg)
    c0 = time.process_time()
    after, _ = postprocess_bytes(before, options=PostprocessOptions(nozzle=NOZZLE,
                                                                       machine=MACHINE))
    pp_cpu = time.process_time() - c0
    t1, r1 = _time(after, cfg, register=False)
    n_rot, t_rot = _rotation_only(r1)
    row = {"name": name, "slicer": t0, "post": t1, "ratio": t1 / t0, "pp_cpu": pp_cpu,
           "stops0": _stops(r0), "stops1": _stops(r1), "rot_only": n_rot, "rot_only_s": t_rot,
           "new_errors": len(r1.errors) - len(r0.errors)}
    _, fast = postprocess_bytes(before, options=PostprocessOptions(
        nozzle=NOZZLE, machine=str(_fast_profile(tmp))))
    row["fast"] = fast.print_time_out / fast.print_time_in
    m = parse_machine(MACHINE)
    free = dataclasses.replace(m.rotary_axis, max_speed=1e9, acceleration=1e9,
                               corner_velocity=1e9)
    t_in = estimate_print_time(parse_gcode(before, path=name), limits=m.planner,
                               rotary=free).total
    t_out = estimate_print_time(parse_gcode(after, path=name), limits=m.planner,
                                rotary=free).total
    row["unlimited"] = t_out / t_in
    if stl is not None:
        out = tmp / "gen.gcode"
        generate_file(stl, out, NOZZLE, MACHINE, layer_height=0.2)
        tg, _ = _time(out.read_bytes(), cfg, register=False)
        row["generated"] = tg
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the cube and one sample only")
    args = ap.parse_args(argv)
    if not klipper_available():
        print("Klipper is not built: run scripts/build-klipper", file=sys.stderr)
        return 1
    exe = shutil.which("prusa-slicer")
    stls = STLS[:1] if args.quick else STLS
    samples = SAMPLES[1:2] if args.quick else SAMPLES
    cfg = _cfg()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if exe is None:
            print("prusa-slicer is not installed (apt-get install prusa-slicer): STLs skipped",
                  file=sys.stderr)
            stls = []
        for name in stls:
            out = tmp / "part.gcode"
            subprocess.run([exe, "--export-gcode", "--load", str(CONFIG), "--center", "110,110",
                            "-o", str(out), str(SHARED / "stl" / name)], check=True,
                           capture_output=True, timeout=3600)
            rows.append(_row(name, out.read_bytes(), cfg, tmp, SHARED / "stl" / name))
            _print(rows[-1])
        for name in samples:
            rows.append(_row(name, (SHARED / "gcode" / name).read_bytes(), cfg, tmp, None))
            _print(rows[-1])
    ratios = [r["ratio"] for r in rows]
    print(f"\npost-processed / slicer on Klipper's planner: {min(ratios):.2f}x .. "
          f"{max(ratios):.2f}x (median {float(np.median(ratios)):.2f}x) over {len(rows)} files")
    fast = [r["fast"] for r in rows]
    print(f"with a rotary axis of {FAST[0]:g} °/s and {FAST[1]:g} °/s² (estimate): "
          f"{min(fast):.2f}x .. {max(fast):.2f}x (median {float(np.median(fast)):.2f}x)")
    free = [r["unlimited"] for r in rows]
    print(f"with the axis's speed, acceleration and corner velocity unlimited (estimate): "
          f"{min(free):.2f}x .. {max(free):.2f}x (median {float(np.median(free)):.2f}x)")
    return 0


def _print(r: dict) -> None:
    gen = f", generated {r['generated']:.0f} s" if "generated" in r else ""
    print(f"{r['name']:<42} slicer {r['slicer']:8.1f} s  post-processed {r['post']:8.1f} s  "
          f"{r['ratio']:5.2f}x  [faster axis {r['fast']:4.2f}x, unlimited {r['unlimited']:4.2f}x]  "
          f"(full stops {r['stops0']} -> {r['stops1']}, rotation-only "
          f"moves {r['rot_only']} = {r['rot_only_s']:.0f} s; post-processing "
          f"{r['pp_cpu']:.1f} s CPU{gen})", flush=True)


if __name__ == "__main__":
    sys.exit(main())
