"""The line-length check follows the firmware the host meets: Marlin cuts lines past its
96-byte buffer (refused before anything is sent), Klipper reads whole lines (a Klipper file's
rotary-axis registration is about 100 bytes)."""

from __future__ import annotations

import subprocess
import sys

import pytest

REGISTER = ("MANUAL_STEPPER STEPPER=c GCODE_AXIS=C LIMIT_VELOCITY=360 LIMIT_ACCEL=3600 "
            "INSTANTANEOUS_CORNER_VELOCITY=30")


@pytest.mark.parametrize(("profile", "ok"), [("klipper", True), ("marlin", False)])
def test_long_line_by_firmware(tmp_path, profile, ok):
    part = tmp_path / "part.gcode"
    part.write_text(f"G28\n{REGISTER}\nG1 X10 Y10 F3000\nM400\n")
    sim = subprocess.Popen([sys.executable, "-m", "printability", "simulate", "--pty",
                            "--clock", "sim", "--quiet", "--profile", profile],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        port = sim.stdout.readline().strip()
        r = subprocess.run([sys.executable, "-m", "printability", "stream", str(part),
                            "--port", port, "--no-progress"], capture_output=True, text=True,
                           timeout=120)
    finally:
        sim.terminate()
        sim.wait(timeout=30)
    text = " ".join(r.stderr.split())
    if ok:
        assert r.returncode == 0, r.stderr
    else:
        assert r.returncode == 1 and "96-byte line buffer" in text and "nothing was sent" in text
