"""The progress bar across layers: drawn on a terminal (stderr on a pty), absent in a pipe."""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys

import pytest

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _run_on_pty(args: list[str], timeout: float = 300) -> tuple[int, str, str]:
    """Run the CLI with stderr on a pseudo-terminal; returns (code, stdout, terminal text)."""
    master, slave = pty.openpty()
    env = {**os.environ, "COLUMNS": "120", "TERM": "xterm"}
    env.pop("PRINTABILITY_PROGRESS", None)
    proc = subprocess.Popen([sys.executable, "-m", "printability", *args], stdout=subprocess.PIPE,
                            stderr=slave, stdin=subprocess.DEVNULL, env=env)
    os.close(slave)
    chunks = []
    try:
        while True:
            ready, _, _ = select.select([master], [], [], timeout)
            if not ready:
                proc.kill()
                pytest.fail("no output on the terminal in time")
            try:
                data = os.read(master, 65536)
            except OSError:      # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        out = proc.stdout.read().decode()
        code = proc.wait(timeout=timeout)
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return code, out, b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.parametrize("workers", ["1", "2"])
def test_progress_bar_on_a_terminal(shared_data, workers):
    code, out, term = _run_on_pty(["analyze", str(shared_data / "stl" / "CalibrationCube.stl"),
                                   "--layer-height", "2", "-n", "circle:d=0.4", "-j", workers])
    assert code == 0, term
    text = ANSI.sub("", term)
    assert "analysing layers" in text
    # the bar counts layer×nozzle tasks and ends full: 10 layers of 2 mm in a 20 mm cube
    assert re.search(r"\b10/10\b", text), text[-2000:]
    assert "circle:d=0.4" in out                                   # the table, on stdout


def test_no_progress_bar_in_a_pipe(shared_data):
    p = subprocess.run([sys.executable, "-m", "printability", "analyze",
                        str(shared_data / "stl" / "CalibrationCube.stl"), "--layer-height", "4",
                        "-n", "circle:d=0.4"], capture_output=True, text=True, timeout=300,
                       env={k: v for k, v in os.environ.items() if k != "PRINTABILITY_PROGRESS"})
    assert p.returncode == 0, p.stderr
    assert "analysing layers" not in p.stderr and "\x1b[" not in p.stderr
