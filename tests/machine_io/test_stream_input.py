"""``printability stream`` and its input (issue #24, item 1): the port is opened before the
file is read, devices and folders are refused at once, and a file is read a piece at a time
into a packed program."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest
from _fake_marlin import FakeMarlin
from hypothesis import given
from hypothesis import strategies as st

import machine_io.program as program_module
from machine_io import Program, load_program, parse_program, state_at
from machine_io.program import PackedNumbers, PackedTexts
from printability.errors import InputError, PrintabilityOSError, ResourceError


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "printability", "stream", *args],
                       capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, "PYTHONUNBUFFERED": "1"})
    r.stderr = " ".join(r.stderr.split())
    return r


@pytest.fixture
def late_failure(tmp_path):
    """A few MB of good G-code whose very last line would be refused: whoever reads the file
    first reports that line."""
    path = tmp_path / "big.gcode"
    with path.open("w") as fh:
        fh.write("G28\nG90\nM82\n")
        for i in range(120_000):
            fh.write(f"G1 X{i % 200}.5 Y{(i * 7) % 200}.25 E{i * 0.01:.4f} F1800\n")
        fh.write("M117 late\x07failure\n")
    return path


def test_the_port_is_checked_before_the_file_is_read(late_failure):
    r = run(str(late_failure), "--port", "/dev/ttyUSB-printability-none", "--no-progress")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "printer port '/dev/ttyUSB-printability-none' does not exist" in r.stderr
    assert "control character" not in r.stderr  # the file was never parsed


def test_the_port_is_opened_before_the_program_is_loaded(late_failure, monkeypatch):
    # in-process: the host opens the port, then the file is read, then the handshake
    import machine_io
    from printability.app.cli.main import run as cli_run

    order: list[str] = []
    real_load = machine_io.load_program

    def load(*a, **k):
        order.append("load")
        return real_load(*a, **k)

    def open_port(self):
        order.append("open")
        raise PrintabilityOSError("no port here")

    monkeypatch.setattr(machine_io, "load_program", load)
    monkeypatch.setattr(machine_io.Host, "open", open_port)
    assert cli_run(["stream", str(late_failure), "--port", "/dev/null", "--no-progress"]) == 1
    assert order == ["open"]


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_devices_are_refused_before_the_port_is_touched(device):
    with FakeMarlin() as fw:
        r = run(device, "--port", fw.path, "--no-progress", timeout=30)
    assert r.returncode == 1 and r.stderr.startswith("printability: error:")
    assert "Traceback" not in r.stderr
    assert f"{device}: cannot read the G-code file: it is a device" in r.stderr
    assert "nothing was sent" in r.stderr
    assert fw.received == []


def test_folders_and_missing_files_are_refused(tmp_path):
    r = run(str(tmp_path), "--port", "/dev/ttyUSB-printability-none", "--no-progress")
    assert r.returncode == 1 and "it is a folder, not a regular file" in r.stderr
    r = run(str(tmp_path / "nope.gcode"), "--port", "/dev/ttyUSB-printability-none")
    assert r.returncode == 1 and "cannot read the G-code file" in r.stderr


def test_a_program_too_big_for_memory_is_refused_with_an_estimate(late_failure):
    with pytest.raises(ResourceError) as e:
        load_program(late_failure, max_memory=1 << 20)
    message = str(e.value)
    assert "MiB" in message and "nothing was sent" in message and str(late_failure) in message


def test_a_loaded_program_is_packed(late_failure):
    late_failure.write_bytes(late_failure.read_bytes().replace(b"late\x07failure", b"done"))
    p = load_program(late_failure, max_line_length=None)
    assert isinstance(p.commands, PackedTexts) and isinstance(p.source_lines, PackedNumbers)
    assert len(p) == 120_004 and p.commands[-1] == "M117 done" and p.source_lines[-1] == 120_004
    assert p.commands[3] == "G1 X0.5 Y0.25 E0.0000 F1800"
    # a few bytes per command, not a Python object each
    assert len(p.commands._blob) + 24 * len(p) < late_failure.stat().st_size * 2
    assert state_at(p, 4).position["X"] == 0.5


def test_packed_sequences_behave_like_tuples():
    p = parse_program(b"G28\n; c\nG1 X1\r\nG1 X2\rN7 G1 X3*99\n", source="t.gcode")
    assert p.commands == ("G28", "G1 X1", "G1 X2", "G1 X3")
    assert p.commands == ["G28", "G1 X1", "G1 X2", "G1 X3"] == list(p.commands)
    assert p.commands[1:3] == ("G1 X1", "G1 X2") and p.commands[-1] == "G1 X3"
    assert p.source_lines == (1, 3, 4, 5) and p.source_lines[::2] == (1, 4)
    assert p.commands != ("G28",) and p.seconds == pytest.approx((0, 0, 0.04, 0.08))
    with pytest.raises(IndexError):
        p.commands[4]
    assert "4 items" in repr(p.commands)
    tupled = Program(p.source, tuple(p.commands), tuple(p.source_lines), tuple(p.seconds),
                     p.axes, p.skipped)
    assert tupled == p and hash(tupled) == hash(p)


@given(st.lists(st.sampled_from([b"G1 X1", b"G28", b"", b"; c", b"M117 \xc3\xa9", b"  G0 Y2 "]),
                max_size=40),
       st.lists(st.sampled_from([b"\n", b"\r\n", b"\r"]), min_size=1, max_size=40),
       st.integers(1, 9))
def test_lines_read_in_pieces_are_the_lines_of_the_whole(parts, ends, chunk):
    data = b"".join(part + ends[i % len(ends)] for i, part in enumerate(parts))
    original = program_module._CHUNK
    program_module._CHUNK = chunk  # pieces cut everywhere, \r\n pairs included
    try:
        got = list(program_module._lines(io.BytesIO(data)))
    finally:
        program_module._CHUNK = original
    assert got == data.splitlines()


def test_resume_from_finds_the_first_command_at_or_after_the_line(tmp_path):
    path = tmp_path / "r.gcode"
    path.write_text("G28\n; c\n\nG1 X1\nG1 X2\n")
    with FakeMarlin() as fw:
        r = run(str(path), "--port", fw.path, "--resume-from", "3", "--no-restore",
                "--no-progress")
        assert r.returncode == 0, r.stderr
        r = run(str(path), "--port", fw.path, "--resume-from", "9", "--no-progress")
    assert [c for c in fw.executed if c.startswith("G1")] == ["G1 X1", "G1 X2"]
    assert r.returncode == 1 and "no command at or after line 9" in r.stderr


def test_a_bad_program_still_sends_nothing(tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_bytes(b"G28\nG1 X1\nM117 \xff\xfe\n")
    with FakeMarlin() as fw:
        r = run(str(bad), "--port", fw.path, "--no-progress")
    assert r.returncode == 1 and "line 3 is not valid UTF-8" in r.stderr
    assert fw.received == []  # the port was opened, nothing was written to it
    with pytest.raises(InputError):
        load_program(bad)
