"""The G-code reader's errors quote at most a short excerpt of the line (issue #24, item 3)."""

from __future__ import annotations

import pytest

from gcode import parse_gcode
from printability.errors import FileFormatError


@pytest.mark.parametrize("line, needle", [
    (b"G1 X1..5 " + b"Y1 " * 1_000_000, "is not a number"),  # the state machine's error
    (b"G1 Xnan " + b"Y1 " * 1_000_000, "X without a number"),  # the bad-number check
    (b"G1 X1e309 " + b"Y1 " * 1_000_000, "exponent notation"),
])
def test_a_megabyte_line_gives_a_short_error(line, needle):
    with pytest.raises(FileFormatError) as e:
        parse_gcode(b"G28\nG1 X0 Y0\n" + line + b"\n", path="long.gcode")
    message = str(e.value)
    assert needle in message and "long.gcode, line 3" in message
    assert len(message) < 1000 and message.count("Y1") < 30
    assert "'…" in message  # the excerpt says it was cut


def test_control_bytes_in_the_excerpt_are_escaped():
    with pytest.raises(FileFormatError) as e:
        parse_gcode(b"G28\nG1 X1..5 M\xff\n", path="x.gcode")
    assert "\\xff" in str(e.value) and "\xff" not in str(e.value)
