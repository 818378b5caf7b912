"""Errors about the content of a G-code file to stream quote a short excerpt (issue #24,
item 3): a 10 MB line is not repeated whole (nor wrapped for minutes)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from machine_io import parse_program
from machine_io.program import Program, check_line_lengths
from printability.errors import InputError

TEN_MB = b"a" * 10_000_000


@pytest.mark.parametrize("line, needle", [
    (b"M117 " + TEN_MB + b"\x01tail", "contains a control character ('\\x01' at column"),
    (b"M117 " + TEN_MB + b"*tail", "contains '*' at column"),
    (b"EXCLUDE_OBJECT_DEFINE NAME=part CENTER=150,150 POLYGON=["
     + b",".join(b"[%d.5,%d.25]" % (i, i) for i in range(600)) + b"\x1b]",
     "contains a control character ('\\x1b'"),
])
def test_a_huge_line_gives_a_short_error(line, needle):
    with pytest.raises(InputError) as e:
        parse_program(b"G28\n" + line + b"\n", source="huge.gcode")
    message = str(e.value)
    assert needle in message and "huge.gcode: line 2" in message
    assert len(message) < 1000


def test_a_long_command_for_a_small_buffer_quotes_its_start():
    p = parse_program(b"M117 " + b"x" * 5000 + b"\n", max_line_length=None)
    with pytest.raises(InputError) as e:
        check_line_lengths(p, 96)
    assert len(str(e.value)) < 400 and "'M117 xxx" in str(e.value)


def test_where_quotes_the_start_of_a_long_command():
    p = Program("p.gcode", ("M117 " + "y" * 10_000,), (1,), (0.0,), frozenset())
    assert len(p.where(0)) < 200 and p.where(0).endswith("…)")


def test_stream_says_it_in_one_short_paragraph(tmp_path):
    path = tmp_path / "huge.gcode"
    path.write_bytes(b"G28\nM117 " + TEN_MB + b"\x01\n")
    r = subprocess.run([sys.executable, "-m", "printability", "stream", str(path), "--port",
                        "loop://", "--no-progress"], capture_output=True, text=True,
                       timeout=120, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert r.returncode == 1 and r.stderr.startswith("printability: error:")
    assert "control character" in r.stderr and len(r.stderr) < 1000
