"""``printability simulate`` tells what it is doing: a line per connection and a periodic
one-line status on stderr, while stdout keeps only the port (scripts read its first line)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_SCRIPT = Path(sys.executable).with_name("printability")
PRINTABILITY = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "printability"]
ENV = dict(os.environ, PYTHONUNBUFFERED="1")

PRINT = ["M104 S210", "M109 S210", "G28", "G90", "M82", "G92 E0", "G1 Z0.2 F600",
         "G1 X10 Y10 F3000", "G1 X30 Y10 E1", "G1 X30 Y30 E2", "G1 Z0.4", "G1 X10 Y30 E3",
         "M400"]


def _simulate_and_stream(tmp_path, *args: str) -> tuple[str, str]:
    """Start the simulator, stream PRINT to it with the real CLI, stop it; its (stdout,
    stderr)."""
    gcode = tmp_path / "print.gcode"
    gcode.write_text("\n".join(PRINT) + "\n")
    sim = subprocess.Popen([*PRINTABILITY, "simulate", "--pty", "--clock", "sim",
                            "--duration", "120", *args],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                           env=ENV)
    try:
        port = sim.stdout.readline()
        assert port.startswith("/dev/"), sim.stderr.read()
        r = subprocess.run([*PRINTABILITY, "stream", str(gcode), "--port", port.strip(),
                            "--no-progress"], capture_output=True, text=True, timeout=60,
                           cwd=ROOT, env=ENV)
        assert r.returncode == 0, r.stderr
        sim.send_signal(signal.SIGTERM)
        out, err = sim.communicate(timeout=30)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert sim.returncode == 0, err
    return port + out, err


def test_connections_and_status_lines_go_to_stderr(tmp_path):
    out, err = _simulate_and_stream(tmp_path, "--status-interval", "0.2")
    assert re.fullmatch(r"/dev/\S+\n", out), out  # stdout: the port and nothing else
    lines = err.splitlines()
    assert lines[0].startswith("simulate: a host opened /dev/"), lines
    assert any(line.startswith("simulate: the host closed /dev/") for line in lines), lines
    status = [line for line in lines if re.match(r"simulate: \d+ commands executed; at X", line)]
    assert status, lines
    # The last status (printed on the way out too): the whole print ran; the head is where
    # the file left it, in layer 2.
    assert re.fullmatch(r"simulate: \d+ commands executed; at X10\.00 Y30\.00 Z0\.40 C0\.00; "
                        r"layer 2 \(Z0\.40\) of 2 deposited; hotend 2\d\d/210 °C, "
                        r"bed \d+/0 °C", status[-1]), status[-1]
    assert lines[-1].startswith("simulate: ") and "commands executed, 0 resends" in lines[-1]


@pytest.mark.parametrize("args", [(), ("--quiet",)])
def test_no_status_lines_unless_asked_when_stderr_is_not_a_terminal(tmp_path, args):
    out, err = _simulate_and_stream(tmp_path, *args)
    assert re.fullmatch(r"/dev/\S+\n", out), out
    lines = err.splitlines()
    assert not [line for line in lines if "; at X" in line], lines
    connections = [line for line in lines if "host opened" in line or "host closed" in line]
    assert len(connections) == (0 if args else 2), lines
    assert "commands executed, 0 resends" in lines[-1]


def test_status_interval_must_be_a_number_of_seconds():
    r = subprocess.run([*PRINTABILITY, "simulate", "--status-interval", "nan", "--duration",
                        "1"], capture_output=True, text=True, timeout=60, cwd=ROOT, env=ENV)
    assert r.returncode == 1 and r.stdout == ""
    assert "--status-interval must be a number of seconds" in r.stderr
