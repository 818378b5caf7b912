"""``analyze``, ``postprocess``, ``generate`` and ``simulate`` as a person runs them: in a real
pseudo-terminal (80 columns), progress displays on. No traceback; what the command promises
is on the screen at the end (its table, its summary, its port). ``stream`` has its own file
(test_stream_terminal.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest
from _cli_helpers import PRINTABILITY, ROOT, env, run_in_terminal, screen


def _shown(status: int | None, out: str) -> str:
    text = "\n".join(screen(out))
    assert status == 0, text
    assert "Traceback" not in out, text
    return text


def test_analyze_in_a_terminal_shows_its_ranking(shared_data):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    text = _shown(*run_in_terminal([*PRINTABILITY, "analyze", str(src), "-n", "circle:d=0.4",
                                    "-n", "ellipse:major=0.8,minor=0.3", "-m", "ttr"],
                                   columns=80, timeout=300))
    assert "rank" in text and "circle:d=0.4" in text and "lost" in text, text
    assert max(len(line) for line in screen(text)) <= 80


def test_postprocess_in_a_terminal_shows_its_summary(shared_data, tmp_path):
    part = tmp_path / "vase.gcode"
    part.write_bytes((shared_data / "gcode" / "prusaslicer_2.7.4_spiral_vase.gcode").read_bytes())
    text = _shown(*run_in_terminal([*PRINTABILITY, "postprocess", str(part), "-n",
                                    "ellipse:major=0.8,minor=0.3", "-o", str(tmp_path / "o.gcode")],
                                   columns=80, timeout=300))
    flat = " ".join(text.split())
    assert "lines in" in flat and "print time" in flat, text
    assert (tmp_path / "o.gcode").stat().st_size > 0


def test_generate_in_a_terminal_shows_its_summary(shared_data, tmp_path):
    out = tmp_path / "cube.gcode"
    text = _shown(*run_in_terminal([*PRINTABILITY, "generate",
                                    str(shared_data / "stl" / "CalibrationCube.stl"), "-o",
                                    str(out), "-n", "circle:d=0.4", "-m", "xy",
                                    "--layer-height", "0.4"], columns=80, timeout=300))
    assert out.stat().st_size > 0
    assert "layers" in " ".join(text.split()), text


def test_simulate_in_a_terminal_says_its_port_and_stops_cleanly(tmp_path):
    """``simulate --pty`` prints its port at once and, stopped with Ctrl-C (SIGINT), ends
    without a traceback."""
    import fcntl
    import select
    import struct
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 80, 0, 0))
    proc = subprocess.Popen([*PRINTABILITY, "simulate", "--pty", "--clock", "sim"],
                            stdin=slave, stdout=slave, stderr=slave, cwd=ROOT,
                            env=env(TERM="xterm-256color"), start_new_session=True)
    os.close(slave)
    out = bytearray()
    try:
        deadline = time.monotonic() + 60
        while b"/dev/pts/" not in out and time.monotonic() < deadline:
            if select.select([master], [], [], 0.2)[0]:
                out += os.read(master, 65536)
        assert b"/dev/pts/" in out, out.decode(errors="replace")
        proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < deadline:
            if select.select([master], [], [], 0.2)[0]:
                try:
                    out += os.read(master, 65536)
                except OSError:
                    break
        try:
            proc.wait(max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
            pytest.fail("simulate did not stop on SIGINT")
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert b"Traceback" not in out, out.decode(errors="replace")
