"""What printability writes, run through the real Klipper host (klippy's parser and planner).

Every file must run on the firmware it names: post-processed slicer files (the real
PrusaSlicer's, and the shared samples) and generated ones, for the bundled Klipper profile,
with no error, unknown command or silently dropped word that the slicer's own file did not
already have, the rotary axis registered before its first word, and the print time Klipper
plans reported beside the slicer's (the ratio is measured in ``benchmarks/bench_klipper.py``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from printability.generate import generate_file
from printability.model.machine import parse_machine
from printability.postprocess import PostprocessOptions, postprocess_bytes
from simulators.klipper_batch import START_END_MACROS, klipper_available, printer_cfg, run_klipper

ROOT = Path(__file__).resolve().parents[2]
PROFILE = "ttr-klipper"
ELLIPSE = "ellipse:major=0.8,minor=0.3"
SLICER_CONFIG = ROOT / "tests" / "postprocess" / "data" / "prusaslicer_ttr.ini"

pytestmark = pytest.mark.skipif(
    not klipper_available() and not os.environ.get("CI"),
    reason="Klipper is not built: run scripts/build-klipper")


def _cfg() -> str:
    m = parse_machine(PROFILE)
    a = m.rotary_axis
    bx0, bx1, by0, by1 = m.bed
    # the printer's C axis as the profile declares it (the file registers it with these)
    return printer_cfg(bed=(bx0, bx1, by0, by1), rotary_velocity=a.max_speed,
                       rotary_accel=a.acceleration, rotary_corner_velocity=a.corner_velocity,
                       extra=START_END_MACROS)


def _complaints(run) -> set[tuple[str, str]]:
    """What Klipper refused, did not know or dropped, without line numbers."""
    out = {("error", msg.split(":")[0]) for _, msg in run.errors}
    out |= {("unknown", cmd) for _, cmd in run.unknown_commands}
    out |= {("ignored", f"{w.command} {w.word[:1]}") for w in run.ignored_words}
    return out


def _turns(run) -> int:
    c = run.moves["rotary"]
    c = c[np.isfinite(c)]
    return int((np.abs(np.diff(c)) > 1e-9).sum())


def _check_postprocessed(before: bytes, after: bytes) -> tuple[float, float]:
    cfg = _cfg()
    r0 = run_klipper(before, cfg=cfg)
    r1 = run_klipper(after, cfg=cfg, register_axes=False)  # the file must register C itself
    assert r1.completed, r1.log[-2000:]
    new = _complaints(r1) - _complaints(r0)
    assert not new, f"Klipper complains about what printability wrote: {sorted(new)[:8]}"
    assert "C" in r1.axes
    assert _turns(r1) > 0  # the nozzle really turns on Klipper's planner
    t0 = r0.print_time - r0.homing_time
    t1 = r1.print_time - r1.homing_time
    print(f"Klipper print time: slicer {t0:.1f} s, post-processed {t1:.1f} s ({t1 / t0:.2f}x)")
    return t0, t1


@pytest.fixture(scope="module")
def prusa_slicer() -> str:
    exe = shutil.which("prusa-slicer")
    if exe is None:
        pytest.skip("prusa-slicer is not installed (Debian: apt-get install prusa-slicer)")
    return exe


def _slice(exe: str, stl: Path, out: Path) -> bytes:
    r = subprocess.run([exe, "--export-gcode", "--load", str(SLICER_CONFIG), "--center",
                        "110,110", "-o", str(out), str(stl)],
                       capture_output=True, text=True, timeout=3600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    return out.read_bytes()


def _prusaslicer_case(exe: str, shared_data: Path, tmp_path: Path, name: str) -> None:
    before = _slice(exe, shared_data / "stl" / name, tmp_path / "part.gcode")
    path = tmp_path / "part.gcode"
    # the plug-in as PrusaSlicer runs it, for the bundled Klipper machine
    r = subprocess.run([sys.executable, "-m", "plugin.prusaslicer", "--nozzle", ELLIPSE,
                        "--machine", PROFILE, "--server", "off", str(path)],
                       capture_output=True, text=True, timeout=1800, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    _check_postprocessed(before, path.read_bytes())


def test_prusaslicer_cube_postprocessed_runs_on_klipper(prusa_slicer, shared_data, tmp_path):
    _prusaslicer_case(prusa_slicer, shared_data, tmp_path, "CalibrationCube.stl")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ThinWall.stl", "3DBenchy_lowpoly.stl", "HoleTest.stl",
                                  "Tolerance.stl", "idler_riser_inches.stl"])
def test_prusaslicer_parts_postprocessed_run_on_klipper(prusa_slicer, shared_data, tmp_path,
                                                        name):
    _prusaslicer_case(prusa_slicer, shared_data, tmp_path, name)


def _sample_case(shared_data: Path, name: str) -> None:
    before = (shared_data / "gcode" / name).read_bytes()
    after, res = postprocess_bytes(before, options=PostprocessOptions(nozzle=ELLIPSE,
                                                                       machine=PROFILE))
    assert res.rotary_words > 0
    _check_postprocessed(before, after)


def test_klipper_sample_postprocessed_runs_on_klipper(shared_data):
    _sample_case(shared_data, "bambustudio_1.10_klipper_arcs.gcode")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["prusaslicer_2.7.4_marlin2_arcs.gcode",
                                  "orcaslicer_2.3.0b2_klipper_arcs.gcode",
                                  "cura_5.9.1_marlin.gcode",
                                  "slic3rpe_1.33_arcwelder_benchy.gcode"])
def test_shared_samples_postprocessed_run_on_klipper(shared_data, name):
    _sample_case(shared_data, name)


@pytest.mark.parametrize("nozzle", [ELLIPSE, "circle:d=0.4"])
def test_generated_cube_runs_on_klipper_on_the_bed(shared_data, tmp_path, nozzle):
    out = tmp_path / "cube.gcode"
    generate_file(shared_data / "stl" / "CalibrationCube.stl", out, nozzle, PROFILE,
                  layer_height=0.2)
    run = run_klipper(out.read_bytes(), cfg=_cfg(), register_axes=False)
    assert run.completed, run.log[-2000:]
    # every word is one Klipper executes (no G92 C, no C on arcs, no unknown command), and
    # every move is inside the bed (else "Move out of range")
    assert not run.errors and not run.unknown_commands and not run.ignored_words, \
        (run.errors[:5], run.unknown_commands[:5], run.ignored_words[:5])
    if nozzle == ELLIPSE:
        assert "C" in run.axes and _turns(run) > 0
    x, y = run.moves["x"], run.moves["y"]
    bx0, bx1, by0, by1 = parse_machine(PROFILE).bed
    assert bx0 <= x.min() and x.max() <= bx1 and by0 <= y.min() and y.max() <= by1


def test_every_bundled_ttr_profile_generates_for_klipper(shared_data, tmp_path):
    """A machine owner switching a bundled T-T-R profile to ``flavor = "klipper"``: what
    ``generate`` writes runs on Klipper, on that profile's bed, the axis registered by the
    file itself (``MANUAL_STEPPER … GCODE_AXIS``), with no word Klipper drops."""
    bundled = Path(__file__).resolve().parents[2] / "printability" / "data" / "machines"
    for name in ("ttr", "ttr-klipper"):
        text = (bundled / f"{name}.toml").read_text()
        text = "\n".join('flavor = "klipper"' if ln.strip().startswith("flavor =") else ln
                         for ln in text.splitlines())
        profile = tmp_path / f"{name}-as-klipper.toml"
        profile.write_text(text + "\n")
        m = parse_machine(str(profile))
        assert m.firmware(None).name == "klipper"
        out = tmp_path / f"{name}.gcode"
        generate_file(shared_data / "stl" / "CalibrationCube.stl", out, ELLIPSE, str(profile),
                      layer_height=0.4)
        a = m.rotary_axis
        bx0, bx1, by0, by1 = m.bed
        cfg = printer_cfg(bed=(bx0, bx1, by0, by1), z_max=400.0, rotary_velocity=a.max_speed,
                          rotary_accel=a.acceleration, rotary_corner_velocity=a.corner_velocity,
                          extra=START_END_MACROS)
        run = run_klipper(out.read_bytes(), cfg=cfg, register_axes=False)
        assert run.completed, (name, run.log[-2000:])
        assert not run.errors and not run.unknown_commands and not run.ignored_words, \
            (name, run.errors[:5], run.unknown_commands[:5], run.ignored_words[:5])
        assert "C" in run.axes and _turns(run) > 0, name
        x, y = run.moves["x"], run.moves["y"]
        assert bx0 <= x.min() and x.max() <= bx1 and by0 <= y.min() and y.max() <= by1, name
