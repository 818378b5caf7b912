"""``analyze``, ``postprocess``, ``generate`` and ``simulate`` as a person runs them: in a real
pseudo-terminal (80 columns), progress displays on. No traceback; what the command promises
is on the screen at the end (its table, its summary, its port). ``stream`` has its own file
(test_stream_terminal.py)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time

import pytest
from _cli_helpers import PRINTABILITY, ROOT, env, run_in_terminal, screen


def _drawn(out: str) -> str:
    """Every frame a live display drew, one per line, colours dropped (what the screen showed
    at some moment, not only at the end)."""
    plain = re.sub(r"\x1b\[[0-9;?]*[@-~]", "", out)
    return "\n".join(f.strip() for f in re.split(r"[\r\n]", plain) if f.strip())


def _shown(status: int | None, out: str) -> str:
    text = "\n".join(screen(out))
    assert status == 0, text
    assert "Traceback" not in out, text
    return text


def test_analyze_in_a_terminal_shows_its_ranking(shared_data):
    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    status, out = run_in_terminal([*PRINTABILITY, "analyze", str(src), "-n", "circle:d=0.4",
                                   "-n", "ellipse:major=0.8,minor=0.3", "-m", "ttr"],
                                  columns=80, timeout=300)
    text = _shown(status, out)
    assert "rank" in text and "circle:d=0.4" in text and "lost" in text, text
    assert max(len(line) for line in screen(text)) <= 80
    # the bar was drawn (its count is "0/?" until the layers are known, and one layer may be
    # done before the next frame)
    assert re.search(r"analysing layers[^\n\d]*\d+/(\d+|\?)", _drawn(out)), _drawn(out)


def test_postprocess_in_a_terminal_shows_its_summary(shared_data, tmp_path):
    part = tmp_path / "vase.gcode"
    part.write_bytes((shared_data / "gcode" / "prusaslicer_2.7.4_spiral_vase.gcode").read_bytes())
    status, out = run_in_terminal([*PRINTABILITY, "postprocess", str(part), "-n",
                                   "ellipse:major=0.8,minor=0.3", "-o", str(tmp_path / "o.gcode")],
                                  columns=80, timeout=300)
    text = _shown(status, out)
    flat = " ".join(text.split())
    assert "lines in" in flat and "print time" in flat, text
    assert (tmp_path / "o.gcode").stat().st_size > 0
    # the progress line was drawn while it ran (then erased): the stages, the layers counted
    drawn = _drawn(out)
    assert "reading the G-code" in drawn and "writing o.gcode" in drawn, drawn
    counts = re.findall(r"planning the layers[^\n\d]*([\d,]+)/([\d,]+)", drawn)
    assert counts and len({total for _, total in counts}) == 1, drawn
    done = [int(d.replace(",", "")) for d, _ in counts]
    assert done == sorted(done) and done[-1] > 0, drawn  # the count goes up
    # a stage without a count shows none (not the layers' of the stage before)
    assert not re.search(r"(rewriting the moves|writing o\.gcode)[^\n\d]*\d+/\d", drawn), drawn


def test_generate_in_a_terminal_shows_its_summary(shared_data, tmp_path):
    out = tmp_path / "cube.gcode"
    status, shown = run_in_terminal([*PRINTABILITY, "generate",
                                     str(shared_data / "stl" / "CalibrationCube.stl"), "-o",
                                     str(out), "-n", "circle:d=0.4", "-m", "xy",
                                     "--layer-height", "0.4"], columns=80, timeout=300)
    text = _shown(status, shown)
    assert out.stat().st_size > 0
    assert "layers" in " ".join(text.split()), text
    drawn = _drawn(shown)  # the progress line while it ran: the stages, the layers counted
    assert "reading CalibrationCube.stl" in drawn and "writing cube.gcode" in drawn, drawn
    assert re.search(r"planning the layers\D*\d+/\d+", drawn), drawn


def test_simulate_in_a_terminal_says_its_port_and_stops_cleanly(tmp_path):
    """``simulate --pty`` prints its port at once, a line per connection and (in a terminal,
    by default) its one-line status; a host streams a short print to it; stopped with Ctrl-C
    (SIGINT), it ends without a traceback, its last status and its summary on the screen."""
    import fcntl
    import select
    import struct
    import termios

    gcode = tmp_path / "print.gcode"
    gcode.write_text("G28\nG90\nG1 X10 Y10 F3000\nG1 X20 Y10\nG1 X20 Y20\nM400\n")
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 80, 0, 0))
    proc = subprocess.Popen([*PRINTABILITY, "simulate", "--pty", "--clock", "sim"],
                            stdin=slave, stdout=slave, stderr=slave, cwd=ROOT,
                            env=env(TERM="xterm-256color"), start_new_session=True)
    os.close(slave)
    out = bytearray()

    def read_until(done, limit: float) -> None:
        deadline = time.monotonic() + limit
        while not done() and time.monotonic() < deadline:
            if select.select([master], [], [], 0.2)[0]:
                try:
                    out.extend(os.read(master, 65536))
                except OSError:  # the simulator has exited
                    break

    try:
        read_until(lambda: re.search(rb"/dev/pts/\d+", out), 60)
        port = re.search(rb"/dev/pts/\d+", out)
        assert port, out.decode(errors="replace")
        r = subprocess.run([*PRINTABILITY, "stream", str(gcode), "--port", port.group(0).decode(),
                            "--no-progress"], capture_output=True, text=True, timeout=120,
                           cwd=ROOT, env=env())
        assert r.returncode == 0, r.stderr
        read_until(lambda: b"the host closed" in out, 30)
        proc.send_signal(signal.SIGINT)
        read_until(lambda: proc.poll() is not None, 30)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
            pytest.fail("simulate did not stop on SIGINT")
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    text = "\n".join(screen(out.decode("utf-8", "replace")))
    assert "Traceback" not in text, text
    flat = " ".join(text.split())
    assert "simulate: a host opened /dev/pts/" in flat and "the host closed" in flat, text
    # the status line (on the way out too, so a short print shows it), then the summary
    assert re.search(r"simulate: \d+ commands executed; at X20\.00 Y20\.00", flat), text
    assert re.search(r"simulate: \d+ commands executed, 0 resends", flat), text
