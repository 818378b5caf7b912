"""``printability stream`` through the real entry point (a subprocess) against the fake Marlin."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from _fake_marlin import FakeMarlin

QUERIES = ("M115", "M114", "M105")
CANCEL = ["M104 S0", "M140 S0", "M107", "M84"]


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "printability", "stream", *args],
                       capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, "PYTHONUNBUFFERED": "1"})
    r.stderr = " ".join(r.stderr.split())  # the error paragraph is wrapped for a terminal
    return r


def printed(fw: FakeMarlin) -> list[str]:
    return [c for c in fw.executed if not c.startswith(QUERIES)]


@pytest.fixture
def gcode(tmp_path):
    path = tmp_path / "part.gcode"
    path.write_text("; a part\nG28\nG90\n" + "".join(f"G1 X{i % 50} Y{i % 7} E{i}\n"
                                                    for i in range(400)))
    return path


def test_stream_prints_the_file_and_writes_a_report(gcode, tmp_path):
    out = tmp_path / "report.json"
    with FakeMarlin(faults={10: ["corrupt"], 50: ["dup_ok"]}) as fw:
        r = run(str(gcode), "--port", fw.path, "--timeout", "0.5", "--no-progress",
                "--json", str(out), "--log", str(tmp_path / "serial.log"))
    assert r.returncode == 0, r.stderr
    assert f"printed {gcode}: 402 of 402 commands" in r.stdout
    lines = gcode.read_text().splitlines()[1:]
    assert printed(fw) == lines
    doc = json.loads(out.read_text())
    assert doc["completed"] and doc["acknowledged"] == 402 and doc["resends"] >= 1
    assert doc["firmware"]["name"] == "Marlin 2.1.2 (fake)"
    assert "Send: N1 G28*" in (tmp_path / "serial.log").read_text()


def test_port_that_does_not_exist(gcode):
    r = run(str(gcode), "--port", "/dev/ttyUSB-printability-none", "--no-progress")
    assert r.returncode == 1 and r.stdout == ""
    assert "printer port '/dev/ttyUSB-printability-none' does not exist" in r.stderr
    assert "Traceback" not in r.stderr


def test_file_with_bytes_that_are_not_utf8(tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_bytes(b"G28\nG1 X1\nM117 \xff\xfe\n")
    with FakeMarlin() as fw:
        r = run(str(bad), "--port", fw.path, "--no-progress")
    assert r.returncode == 1
    assert "line 3 is not valid UTF-8" in r.stderr and "nothing was sent" in r.stderr
    assert fw.received == []  # refused before the port was even opened


def test_printer_that_never_answers(gcode):
    with FakeMarlin(answer=False, banner=False) as fw:
        r = run(str(gcode), "--port", fw.path, "--no-progress")
    assert r.returncode == 1
    assert "did not answer" in r.stderr and "nothing of the file was sent" in r.stderr
    assert "Traceback" not in r.stderr


def test_ctrl_c_cancels_cleanly_and_says_where(tmp_path):
    long = tmp_path / "long.gcode"
    long.write_text("G28\n" + "".join(f"G1 X{i % 50} Y{i % 7}\n" for i in range(200000)))
    with FakeMarlin() as fw:
        proc = subprocess.Popen([sys.executable, "-m", "printability", "stream", str(long),
                                 "--port", fw.path, "--no-progress"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            # the file's own commands, not the host's queries (M115 first): at least 500
            # of them run before the interrupt
            while len(printed(fw)) < 500 and time.monotonic() < deadline:
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60)
            err = " ".join(err.split())
        finally:
            if proc.poll() is None:
                proc.kill()
        time.sleep(0.2)
        got = printed(fw)
    assert proc.returncode == 1, err
    assert "cancelled by Ctrl-C" in err and "--resume-from" in err
    commands = long.read_text().splitlines()
    n = len(got) - len(CANCEL)
    assert 500 <= n < len(commands)
    assert got == [*commands[:n], *CANCEL]
    # The line to resume from is the first one not run.
    assert f"--resume-from {n + 1}" in err


def test_resume_from_a_line_restores_the_state(tmp_path):
    path = tmp_path / "r.gcode"
    path.write_text("M104 S200\nG28\nG1 X5 Y5 Z0.2 E1 F1200\nG1 X6 E2\nG1 X7 E3\n")
    with FakeMarlin() as fw:
        r = run(str(path), "--port", fw.path, "--no-progress", "--resume-from", "5")
    assert r.returncode == 0, r.stderr
    got = printed(fw)
    assert got[-1] == "G1 X7 E3" and "M109 S200" in got and "G92 E2.00000" in got
    assert "G1 X6 E2" not in got
