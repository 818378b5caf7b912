"""machine_io.protocol and machine_io.program: framing, replies, loading, state, estimate."""

from __future__ import annotations

import functools
import operator

import pytest

from machine_io.program import (
    MachineState,
    load_program,
    parse_program,
    restore_commands,
    state_at,
)
from machine_io.protocol import (
    checksum,
    command_code,
    frame,
    is_protocol_error,
    parse_firmware_info,
    parse_position,
    parse_reply,
    parse_temperatures,
)
from printability.errors import InputError, PrintabilityOSError


@pytest.mark.parametrize("number, command", [(0, "M110 N0"), (1, "G28"), (123456, "G1 X1.5 E-2")])
def test_frame_is_marlin_line_with_xor_checksum(number, command):
    data = frame(number, command)
    body, _, tail = data.rpartition(b"*")
    assert body == f"N{number} {command}".encode()
    assert tail.endswith(b"\n") and int(tail) == functools.reduce(operator.xor, body, 0)
    assert checksum(body) == int(tail)


@pytest.mark.parametrize("text, kind, number, planner, buffer", [
    ("ok", "ok", None, None, None),
    ("ok N12 P15 B3", "ok", 12, 15, 3),
    ("ok P15 B0", "ok", None, 15, 0),
    ("ok T:210.0 /210.0 B:60.0 /60.0 @:127 B@:0", "ok", None, None, None),
    ("Resend: 42", "resend", 42, None, None),
    ("Resend:7", "resend", 7, None, None),
    ("rs N42", "resend", 42, None, None),
    ("echo:busy: processing", "busy", None, None, None),
    ("busy: heating", "busy", None, None, None),
    ("Error:checksum mismatch, Last Line: 41", "error", None, None, None),
    ("Error:Printer halted. kill() called!", "error", None, None, None),
    ("start", "start", None, None, None),
    ("//action:pause", "action", None, None, None),
    ("FIRMWARE_NAME:Marlin 2.1.2 AXIS_COUNT:4", "firmware", None, None, None),
    ("Cap:ADVANCED_OK:1", "cap", None, None, None),
    ("T:20.5 /0.0 B:21.0 /0.0 @:0 B@:0", "temperature", None, None, None),
    ("X:1.00 Y:2.00 Z:3.00 C:90.00 E:0.00 Count X:80 Y:160 Z:1200 C:900", "position", None,
     None, None),
    ("echo:Unknown command: \"G999\"", "echo", None, None, None),
    ("okay then", "other", None, None, None),
])
def test_parse_reply_classifies_marlin_lines(text, kind, number, planner, buffer):
    r = parse_reply(text)
    assert (r.kind, r.number, r.planner, r.buffer) == (kind, number, planner, buffer)


@pytest.mark.parametrize("text, protocol", [
    ("Error:checksum mismatch, Last Line: 41", True),
    ("Error:Line Number is not Last Line Number+1, Last Line: 9", True),
    ("Error:No Checksum with line number, Last Line: 3", True),
    ("Error:MINTEMP triggered, system stopped! Heater_ID: 0", False),
    ("Error:Thermal Runaway, system stopped! Heater_ID: bed", False),
])
def test_protocol_errors_are_told_from_printer_faults(text, protocol):
    assert is_protocol_error(text) is protocol


def test_temperatures_and_positions():
    assert parse_temperatures("ok T:210.2 /210.0 B:59.9 /60.0 @:127 B@:0") == {
        "T": (210.2, 210.0), "B": (59.9, 60.0)}
    assert parse_temperatures("T0:20 /0 T1:21.5 /200 B:20 /0") == {
        "T0": (20.0, 0.0), "T1": (21.5, 200.0), "B": (20.0, 0.0)}
    assert parse_temperatures("ok") == {}
    pos = parse_position("X:10.00 Y:20.00 Z:0.30 C:-45.00 E:1.50 Count X:800 Y:1600 Z:120 C:9")
    assert pos == {"X": 10.0, "Y": 20.0, "Z": 0.3, "C": -45.0, "E": 1.5}
    assert parse_position("echo: nothing here") is None


@pytest.mark.parametrize("m114, axis_count, letter, expected", [
    ("X:0 Y:0 Z:0 C:0 E:0 Count X:0", "4", "C", True),
    ("X:0 Y:0 Z:0 E:0 Count X:0", "4", "C", False),  # M114 is authoritative
    (None, "3", "C", False),
    (None, "4", "C", None),  # an extra axis exists but its letter is unknown
    (None, None, "C", None),
])
def test_firmware_reports_its_axes(m114, axis_count, letter, expected):
    lines = ["FIRMWARE_NAME:Marlin 2.1.2.4 (sim) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
             "PROTOCOL_VERSION:1.0 MACHINE_TYPE:TTR EXTRUDER_COUNT:1"
             + (f" AXIS_COUNT:{axis_count}" if axis_count else ""),
             "Cap:ADVANCED_OK:1", "Cap:EEPROM:0"]
    info = parse_firmware_info(lines, parse_position(m114) if m114 else None)
    assert info.name == "Marlin 2.1.2.4 (sim)"
    assert info.fields["MACHINE_TYPE"] == "TTR"
    assert info.advanced_ok and not info.cap("EEPROM")
    assert info.has_axis(letter) is expected


@pytest.mark.parametrize("text, code", [("G1 X1", "G1"), ("g01 x1", "G1"), ("M862.3 P1", "M862.3"),
                                        ("T0", "T0"), ("START_PRINT", ""), ("G", "")])
def test_command_code(text, code):
    assert command_code(text) == code


def test_program_drops_comments_and_blank_lines_and_keeps_source_lines():
    data = b"; header\n\nG28 ; home\n  G1 X1 Y2  \n;only comment\nN5 G1 X3*33\nM110 N0\nG1 X4\n"
    p = parse_program(data, source="t.gcode")
    assert p.commands == ("G28", "G1 X1 Y2", "G1 X3", "G1 X4")
    assert p.source_lines == (3, 4, 6, 8)
    assert p.skipped == ((7, "M110 not sent: the host numbers the lines itself"),)
    assert p.where(1) == "command 2 of 4 (t.gcode line 4: G1 X1 Y2)"


def test_non_utf8_in_a_comment_is_dropped_with_it():
    p = parse_program(b"G28 ; caf\xe9\nG1 X1\n")
    assert p.commands == ("G28", "G1 X1")


@pytest.mark.parametrize("data, needle", [
    (b"G28\nG1 X\xff1\n", "line 2 is not valid UTF-8 (byte 0xff at column 5)"),
    (b"G28\nM117 a*b\n", "line 2 contains '*'"),
    (b"G28\nM117 a\x07b\n", "line 2 contains a control character"),
    (b"G28\nM117 " + b"x" * 100 + b"\n", "line 2 is 1"),
    (b"; nothing\n\n", "no G-code command"),
])
def test_bad_programs_are_refused_before_anything_is_sent(data, needle):
    with pytest.raises(InputError) as e:
        parse_program(data, source="bad.gcode")
    assert needle in str(e.value) and "bad.gcode" in str(e.value)


def test_load_program_errors(tmp_path):
    with pytest.raises(PrintabilityOSError, match="cannot read"):
        load_program(tmp_path / "missing.gcode")
    binary = tmp_path / "b.gcode"
    binary.write_bytes(b"G28\n\x00\x01\x02")
    with pytest.raises(InputError, match="binary"):
        load_program(binary)


def test_estimate_is_length_over_feed():
    p = parse_program(b"G90\nG1 X0 Y0 F600\nG1 X10 F600\nG1 Y10\nG4 S2\nG91\nG1 X-3 Y-4\n"
                      b"G1 E-1 F60\n")
    # 0, 10 mm at 10 mm/s, 10 mm, dwell 2 s, 5 mm relative, 1 mm of filament at 1 mm/s
    assert p.seconds == pytest.approx((0, 0, 1, 2, 4, 4, 4.5, 5.5))
    assert p.axes == {"X", "Y", "E"}


def test_rotary_axes_are_found():
    p = parse_program(b"G1 X1 Y1 C90 E1\nG92 C0\n")
    assert p.rotary_axes == {"C"}


def test_state_follows_modes_positions_and_temperatures():
    p = parse_program(b"M140 S60\nM104 S210\nG90\nM82\nG92 E0\nG1 X10 Y5 Z0.3 C45 E1 F1200\n"
                      b"M106 S128\nG91\nG1 X1 C10\nM83\nG1 E0.5\nM109 S215\n")
    s = state_at(p, len(p))
    assert s.position == {"X": 11.0, "Y": 5.0, "Z": 0.3, "C": 55.0, "E": 1.5}
    assert (s.absolute, s.e_absolute, s.feed, s.fan) == (False, False, 1200.0, 128)
    assert s.temperatures == {"B": 60.0, "T": 215.0}
    assert state_at(p, 6).position["C"] == 45.0
    assert MachineState().apply("G92").position == {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}


def test_restore_heats_declares_homes_travels_and_restores_modes():
    s = state_at(parse_program(b"M140 S60\nM104 S210\nG1 X10 Y5 Z2 C45 E3 F1200\nM83\n"), 4)
    cmds = restore_commands(s, home_xy=True, lift=1.0)
    assert cmds == ("M140 S60", "M104 S210", "M190 S60", "M109 S210", "G90",
                    "G92 Z2.0000 C45.0000", "G1 Z3.0000 F600", "G28 X Y",
                    "G1 X10.0000 Y5.0000 F3000", "G1 Z2.0000 F600", "G92 E3.00000", "M83",
                    "G1 F1200")
    assert "G28 X Y" not in restore_commands(s, home_xy=False)


def test_real_slicer_files_load(shared_data):
    for name in ("prusaslicer_2.7.4_marlin2_arcs.gcode", "cura_5.9.1_marlin.gcode"):
        p = load_program(shared_data / "gcode" / name)
        assert len(p) > 1000 and p.total_seconds > 60
        assert all(c == c.strip() and ";" not in c for c in p.commands)


def _report(injected=(), in_doubt=()):
    from types import SimpleNamespace

    return SimpleNamespace(injected=tuple(injected), in_doubt=tuple(in_doubt))


def test_executed_as_streamed_allows_only_the_in_doubt_repeat():
    from machine_io import executed_as_streamed

    cmds = [f"G1 X{i}" for i in range(6)]
    restore = ["M104 S200", "G92 E0"]
    rep = _report([(3, restore), (6, ("M105",))], [(3, 2)])
    ok = cmds[:3] + restore + cmds[3:] + ["M105"]
    assert executed_as_streamed(ok, cmds, rep)
    # the first or both unacknowledged commands also ran before the restart
    assert executed_as_streamed(cmds[:4] + restore + cmds[3:] + ["M105"], cmds, rep)
    assert executed_as_streamed(cmds[:5] + restore + cmds[3:] + ["M105"], cmds, rep)
    # but not a third one, nor any repeat without a restart, nor a loss, nor a swap
    assert not executed_as_streamed(cmds[:6] + restore + cmds[3:] + ["M105"], cmds, rep)
    assert not executed_as_streamed(cmds[:4] + restore + cmds[3:] + ["M105"], cmds,
                                    _report([(3, restore), (6, ("M105",))]))
    assert not executed_as_streamed(cmds[:3] + restore + cmds[4:] + ["M105"], cmds, rep)
    swapped = cmds[:3] + restore + [cmds[4], cmds[3], cmds[5]] + ["M105"]
    assert not executed_as_streamed(swapped, cmds, rep)
