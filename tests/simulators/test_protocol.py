"""Marlin host protocol of the simulator: checksums, resends with Marlin's exact strings,
M110, ADVANCED_OK, pacing by the queue and planner, reports, kill, malformed input."""

from __future__ import annotations

import math
import re

import pytest
from _sim_helpers import framed, open_sim, xor
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from printability.errors import InputError
from simulators import Firmware, checksum, make_config


def _fw(**kw) -> Firmware:
    fw = Firmware(make_config(**kw))
    fw.connect()
    fw.take_output()
    return fw


def _say(fw: Firmware, data: bytes) -> str:
    fw.receive(data)
    fw.run_sim()
    return b"".join(x for x in fw.take_output() if isinstance(x, bytes)).decode("latin-1")


@pytest.mark.parametrize("text", ["N0 M110 N0", "N1 M115", "N12 G1 X10.5 Y-3 E0.25 F1800",
                                  "N99999 M104 S215"])
def test_checksum_matches_independent_xor(text):
    assert checksum(text) == xor(text)


@pytest.mark.parametrize("profile", ["marlin", "marlin-advanced"])
def test_banner_on_connect(profile):
    with open_sim(f"profile={profile}") as ser:
        banner = ser.read(4096).decode()
    assert banner.splitlines()[0] == "start"


@pytest.mark.parametrize(("line", "expected"), [
    (b"N2 M105*99\n", "Error:Line Number is not Last Line Number+1, Last Line: 0"),
    (b"N1 M105*1\n", "Error:checksum mismatch, Last Line: 0"),
    (b"N1 M105\n", "Error:No Checksum with line number, Last Line: 0"),
    (b"M105*35\n", "Error:No Line Number with checksum, Last Line: 0"),
])
@pytest.mark.parametrize("ok_after", [True, False])
def test_resend_exact_strings(line, expected, ok_after):
    fw = _fw(firmware={"ok_after_resend": ok_after})
    out = _say(fw, line).splitlines()
    assert out[:2] == [expected, "Resend: 1"]
    assert out[2:] == (["ok"] if ok_after else [])
    assert fw.executed == []


def test_error_empties_the_receive_ring():
    fw = _fw()
    # The second line arrives together with the bad one: Marlin drains it unread.
    out = _say(fw, b"N1 M105*1\n" + framed(2, "M105"))
    assert out.splitlines() == ["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
    assert fw.executed == []


def test_line_numbers_and_m110():
    fw = _fw()
    assert _say(fw, framed(1, "M400")).strip() == "ok"
    assert _say(fw, framed(5, "M110 N5")).strip() == "ok"
    assert _say(fw, framed(6, "M400")).strip() == "ok"
    # Printrun starts a print with 'N-1 M110 N-1': the next line is N0.
    assert _say(fw, framed(-1, "M110 N-1")).strip() == "ok"
    assert _say(fw, framed(0, "G90")).strip() == "ok"
    assert [n for n, _ in fw.executed] == [1, 5, 6, -1, 0]
    out = _say(fw, framed(0, "G90"))
    assert out.splitlines()[0] == "Error:Line Number is not Last Line Number+1, Last Line: 0"


def test_advanced_ok_fields():
    fw = _fw(profile="marlin-advanced", firmware={"planner_buffer": 8, "command_buffer": 4})
    assert _say(fw, framed(1, "M302 P1")).strip() == "ok N1 P8 B3"
    assert _say(fw, framed(2, "G1 X10 F600")).strip() == "ok N2 P7 B3"
    assert _say(fw, framed(3, "G1 X20")).strip() == "ok N3 P6 B3"
    assert _say(fw, b"G1 X30\n").strip() == "ok P5 B3"  # no N when the line had none


def test_plain_ok_without_advanced():
    fw = _fw(profile="marlin")
    assert _say(fw, framed(1, "G1 X10 F600")).strip() == "ok"


@pytest.mark.parametrize(("planner", "queue"), [(16, 4), (4, 2), (1, 1)])
def test_planner_and_queue_pace_the_oks(planner, queue):
    """With the clock held at 0, exactly `planner` moves are acknowledged; each finished
    block then lets one more through."""
    fw = Firmware(make_config(firmware={"planner_buffer": planner, "command_buffer": queue}))
    fw.connect()
    fw.take_output()
    n = planner + queue + 10
    data = b"".join(f"G1 X{(i % 2) * 50 + 10} Y10 F6000\n".encode() for i in range(n))
    fw.receive(data, 0.0)
    fw.advance(0.0)
    out = b"".join(x for x in fw.take_output() if isinstance(x, bytes)).decode()
    assert out.count("ok") == planner
    assert len(fw._queue) == queue
    first_end = fw._exec_end
    fw.advance(first_end)
    out = b"".join(x for x in fw.take_output() if isinstance(x, bytes)).decode()
    assert out.count("ok") == 1


def test_full_ring_holds_bytes_back_or_drops_them():
    big = b"".join(b"G4 P0\n" for _ in range(200))
    held = _fw(firmware={"rx_buffer": 128})
    held.receive(big, 0.0)
    held.advance(0.0)
    dropped = _fw(firmware={"rx_buffer": 128, "rx_overflow_drops": True})
    dropped.receive(big, 0.0)
    dropped.advance(0.0)
    assert held.stats.bytes_dropped == 0
    assert dropped.stats.bytes_dropped == len(big) - 128
    held.run_sim()
    assert len(held.executed) == 200


@pytest.mark.parametrize("baud", [9600, 115200, 250000])
def test_baud_pacing_moves_the_simulated_clock(baud):
    fw = _fw(baud=baud)
    data = b"".join(framed(i, "M400") for i in range(1, 41))
    fw.receive(data)
    fw.run_sim()
    assert fw.now == pytest.approx(len(data) * 10 / baud, rel=1e-9)
    assert len(fw.executed) == 40


def test_run_until_says_each_answer_at_the_time_its_line_arrives():
    baud = 250000
    fw = _fw(baud=baud, clock="real")
    lines = [framed(1, "M400"), framed(2, "G4 P10"), framed(3, "M400")]
    for line in lines:  # one write each, all at t = 0: they queue on the wire
        fw.receive(line, now=0.0)
    arrive = [sum(map(len, lines[:k + 1])) * 10 / baud for k in range(3)]
    fw.run_until(fw.pending_until())  # ahead of any wall clock: up to line 3's arrival
    assert fw.now == pytest.approx(arrive[2])
    first = fw.take_output_timed()
    assert first == [(pytest.approx(arrive[0]), b"ok\n")]  # line 2 is still dwelling
    fw.run_until(1.0)
    # line 2 dwells 10 ms: its ok, and line 3's (queued behind it), at the dwell's end
    assert fw.take_output_timed() == [(pytest.approx(arrive[1] + 0.010), b"ok\nok\n")]


@pytest.mark.parametrize(("cmd", "busy"), [("G4 S5", 2), ("G4 P1000", 0), ("G28", 2)])
def test_busy_while_blocked(cmd, busy):
    fw = _fw(firmware={"homing_time": 5.0})
    out = _say(fw, f"{cmd}\n".encode()).splitlines()
    assert out == ["echo:busy: processing"] * busy + ["ok"]


def test_unknown_commands_as_marlin_and_klipper():
    fw = _fw()
    out = _say(fw, b"START_PRINT EXTRUDER_TEMP=200 BED_TEMP=60\nM9876 S1\n").splitlines()
    assert out == ['echo:Unknown command: "START_PRINT EXTRUDER_TEMP=200 BED_TEMP=60"', "ok",
                   'echo:Unknown command: "M9876 S1"', "ok"]
    kl = _fw(profile="klipper")
    out = _say(kl, b"START_PRINT EXTRUDER_TEMP=200\nFROB X=1\nN7 M105*99\n").splitlines()
    assert out[0] == "ok"  # a macro
    assert out[1:3] == ['// Unknown command:"FROB"', "ok"]
    assert out[3].startswith("ok B:")  # checksums ignored, no Resend


@pytest.mark.parametrize(("profile", "adv"), [("marlin", 0), ("marlin-advanced", 1)])
def test_m115_reports_capabilities_and_rotary_axis(profile, adv):
    fw = _fw(profile=profile, machine="ttr:min=-90,max=90,letter=A")
    out = _say(fw, b"M115\n").splitlines()
    assert out[0].startswith("FIRMWARE_NAME:Marlin")
    assert "AXIS_COUNT:4" in out[0]
    assert f"Cap:ADVANCED_OK:{adv}" in out
    assert "Cap:ROTARY_AXIS:A" in out
    assert any("min:-90 max:90" in line for line in out)
    assert out[-1].startswith("ok")


def test_m114_and_modes():
    fw = _fw()
    cmds = ["G28", "G1 X10 Y20 Z0.3 C45 F3000", "G91", "G1 X5 C-90", "G90", "G92 X0 Y0",
            "G1 X1", "M83", "G1 E2", "G1 E3", "M82", "G92 E10", "G1 E12", "M114"]
    out = _say(fw, "".join(c + "\n" for c in cmds).encode()).splitlines()
    pos = next(line for line in out if line.startswith("X:"))
    assert pos.startswith("X:1.00 Y:0.00 Z:0.30 C:-45.00 E:12.00 Count X:1280 Y:1600 Z:120 C:-450")


@pytest.mark.parametrize(("profile", "line", "expect_x"), [
    ("marlin", "G1 X500 Y-5", 220.0), ("klipper", "G1 X500 Y-5", 0.0)])
def test_soft_endstops(profile, line, expect_x):
    fw = _fw(profile=profile)
    out = _say(fw, f"G28\n{line}\nM114\n".encode())
    assert fw.motion.pos[0] == expect_x
    if profile == "klipper":
        assert "!! Move out of range: 500.000 -5.000 0.000 [0.000]" in out


def test_rotary_limits_from_machine():
    fw = _fw(machine="ttr:min=-90,max=90")
    _say(fw, b"G1 C120\n")
    assert fw.motion.pos[3] == 90.0
    full = _fw(machine="ttr")  # the shipped profile: a full turn, no limit
    _say(full, b"G1 C720\n")
    assert full.motion.pos[3] == 720.0


def test_arc_end_point_and_segments():
    fw = _fw()
    _say(fw, b"G28\nG1 X20 Y10 F3000\nG2 X10 Y20 I-10 J0\nM400\n")
    assert fw.motion.pos[:2] == pytest.approx([10.0, 20.0])
    # Marlin: at least 72 segments per turn, none longer than 1 mm; a 270 degree arc of r=10
    assert fw.stats.blocks == 1 + max(math.ceil(1.5 * math.pi * 10), math.ceil(72 * 0.75))


def test_heating_model_and_reports():
    fw = _fw()
    out = _say(fw, b"M104 S200\nM105\n").splitlines()
    assert re.match(r"ok T:22\.00 /200\.00 B:22\.00 /0\.00 @:127 B@:0", out[1])
    t0 = fw.now
    out = _say(fw, b"M109 S200\n").splitlines()
    tau, res = fw.fw.hotend_tau, fw.fw.hotend_residency
    assert fw.now - t0 == pytest.approx(tau * math.log(178.0 / 1.0) + res, rel=1e-6)
    assert out[-1] == "ok"
    assert len(out) - 1 == math.ceil(fw.now - t0) - 1  # one report per second while waiting
    assert abs(fw.hotend.temp(fw.now) - 200) < 1.0
    out = _say(fw, b"M190 S60\nM155 S2\nG4 S5\n").splitlines()
    assert sum(1 for line in out if line.startswith(" T:") and "W:" not in line) == 2


def test_m112_kills():
    fw = _fw()
    out = _say(fw, b"G28\nM112\nM105\n")
    assert "Error:Printer halted. kill() called!" in out
    assert _say(fw, b"M105\n") == ""
    assert fw.halted


@pytest.mark.parametrize("junk", [
    b"\xff\xfe\x00garbage\x80\x81\n",
    b"G1 X--1 Y2..3 E+-4\n",
    b"N1 G1 X1" + b"9" * 10_000 + b"*12\n",
    b"M104 S" + b"1" * 10_000 + b"\n",
    b"G1 X1e999999\n",
    b"\xc3\x28\xa0\xa1 M105\n",
    b"*\n", b"N\n", b"N*\n", b"N-\n", b"M\n", b"G\n", b";;;;\n",
])
def test_malformed_input_answers_like_firmware(junk):
    fw = _fw()
    _say(fw, junk)
    _say(fw, b"\n")
    out = _say(fw, b"M105\n")
    assert "ok T:" in out


def test_long_line_is_truncated_like_marlin():
    fw = _fw()
    out = _say(fw, b"N1 M117 " + b"x" * 10_000 + b"*99\n")
    # MAX_CMD_SIZE: the checksum is cut off with the rest of the line.
    assert out.splitlines()[0] == "Error:No Checksum with line number, Last Line: 0"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=3000))
def test_random_bytes_never_crash(data):
    fw = _fw()
    _say(fw, data)
    _say(fw, b"\n")  # ends a partial line; an error there drains what came with it
    out = _say(fw, b"M105\n")
    if fw.halted:  # the bytes held an M112: a killed Marlin says nothing more
        assert out == ""
    else:
        assert "ok T:" in out


def _motion_time(cmds: list[str], **kw) -> float:
    fw = _fw(**kw)
    _say(fw, "".join(c + "\n" for c in cmds).encode())
    fw.drain()
    return fw.stats.motion_time


@pytest.mark.parametrize(("cmds", "expected"), [
    # 100 mm at 100 mm/s, 1000 mm/s²: 0.1 s up, 0.1 s down, 90 mm cruise.
    (["G1 X100 F6000"], 1.1),
    # Collinear blocks keep their speed through the junction: as one 200 mm move.
    (["G1 X100 F6000", "G1 X200"], 2.1),
    # A reversal stops: two separate trapezoids.
    (["G1 X100 F6000", "G1 X0"], 2.2),
    # Too short to reach the feed: triangle profile, 2·sqrt(L/a).
    (["G1 X1 F6000"], 2 * math.sqrt(1 / 1000)),
    # Rotary only: F in degrees/min (Marlin 2.1), the machine's [rotary] acceleration
    # (3600 deg/s² for the built-in ttr).
    (["G1 C360 F3600"], 60 / 3600 + 360 / 60 - 60 / 3600 + 60 / 3600),
])
def test_trapezoid_motion_time(cmds, expected):
    assert _motion_time(["G28", *cmds], machine="ttr:letter=C") == pytest.approx(expected)


def _machine_file(tmp_path, policy: str) -> str:
    path = tmp_path / f"m_{policy}.toml"
    path.write_text(f'[machine]\nname = "t"\nkind = "ttr"\n[bed]\nx = [0.0, 200.0]\n'
                    f'y = [0.0, 200.0]\n[firmware]\nflavor = "marlin"\n'
                    f'feed_policy = "{policy}"\nplanner_buffer = 5\nacceleration = 2000.0\n')
    return str(path)


def test_feed_policies(tmp_path):
    # xy: F is the XY speed; the rotary axis follows in the same time.
    xy = _motion_time(["G28", "G1 X100 C90 F6000"], machine=_machine_file(tmp_path, "xy"))
    assert xy == pytest.approx(0.05 + 0.05 + 95 / 100)  # 2.5 mm ramps at 2000 mm/s²
    # euclidean: degrees count as mm in the length.
    eu = _motion_time(["G28", "G1 X100 C90 F6000"],
                      machine=_machine_file(tmp_path, "euclidean"))
    length = math.hypot(100, 90)
    assert eu == pytest.approx(0.1 + (length - 5) / 100)
    # inverse time: G93 F2 = the move lasts half a minute, whatever its length.
    it = _motion_time(["G28", "G93", "G1 X100 C90 F2", "G94"],
                      machine=_machine_file(tmp_path, "inverse-time"))
    assert it == pytest.approx(30.0)
    # The profile's [firmware] table sets the buffers.
    fw = _fw(machine=_machine_file(tmp_path, "xy"))
    assert fw.fw.planner_buffer == 5 and fw.fw.acceleration == 2000.0
    out = _say(fw, b"G93\n")
    assert out.startswith('echo:Unknown command: "G93"')


def test_machine_profile_firmware_keys_are_checked(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text('[machine]\nname = "t"\nkind = "ttr"\n[firmware]\nflavor = "marlin"\n'
                    'planner_buffr = 8\n')
    with pytest.raises(InputError, match="unknown \\[firmware\\] key 'planner_buffr'"):
        make_config(machine=str(path))


@pytest.mark.parametrize("profile", ["marlin", "marlin-advanced", "klipper"])
def test_every_profile_runs_on_the_shipped_ttr_machine(profile):
    fw = _fw(profile=profile, machine="ttr")
    out = _say(fw, b"G28\nG1 X10 Y10 C90 F3000\nM114\n")
    assert "C:90.00" in out


@pytest.mark.parametrize("line", [b"M112\n", b"N7 M112*99\n", b"  M112 ; stop\r\n"])
def test_emergency_parser_kills_while_the_queue_is_full(line):
    fw = _fw(firmware={"command_buffer": 2})
    fw.receive(b"G4 S100\nG4 S100\nG4 S100\nG4 S100\n", 0.0)
    fw.advance(0.0)
    assert len(fw._queue) == 2
    fw.receive(line, 0.0)
    fw.advance(0.0)
    assert fw.halted
    out = b"".join(x for x in fw.take_output() if isinstance(x, bytes)).decode()
    assert out.endswith("Error:Printer halted. kill() called!\n")
