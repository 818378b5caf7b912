"""Fault injection: scheduled faults do exactly what they say, random ones are reproducible
from their seed, and a correct host still gets every line executed once, in order."""

from __future__ import annotations

import pytest
import serial
from _sim_helpers import MiniHost, framed, open_sim

from printability.errors import InputError
from simulators import FaultPlan, Firmware, make_config
from simulators.firmware import Disconnect, Stall

COMMANDS = ["M302 P1", "G28", *[f"G1 X{10 + i % 7} Y{10 + i % 5} E{0.1 * i:.1f} F3000"
                               for i in range(1, 60)], "M400"]


def _run(faults: str, seed: int, profile: str = "marlin-advanced") -> tuple[list, list, list]:
    with open_sim(f"profile={profile}&faults={faults}&seed={seed}") as ser:
        host = MiniHost(ser)
        host.stream(COMMANDS)
        fw = ser.simulator.firmware
        return host.transcript, list(fw.executed), list(fw.stats.faults)


def _fw(faults: str, **kw) -> Firmware:
    fw = Firmware(make_config(faults=faults, **kw))
    fw.connect()
    fw.take_output()
    return fw


def _say(fw: Firmware, data: bytes) -> list:
    fw.receive(data)
    fw.run_sim()
    return fw.take_output()


def _text(items: list) -> list[str]:
    return b"".join(x for x in items if isinstance(x, bytes)).decode("latin-1").splitlines()


@pytest.mark.parametrize(("spec", "message"), [
    ("bogus@3", "unknown fault kind"), ("drop-ok", "KIND@LINE"), ("stall@x", "integer line"),
    ("corrupt~1.5", "probability"), ("stall@3:-1", "non-negative"),
])
def test_fault_spec_errors(spec, message):
    with pytest.raises(InputError, match=message):
        FaultPlan.parse(spec)


def test_drop_line_is_caught_by_line_numbers():
    fw = _fw("drop-line@2")
    assert _text(_say(fw, framed(1, "M400"))) == ["ok"]
    assert _text(_say(fw, framed(2, "M400"))) == []  # lost on the wire
    assert _text(_say(fw, framed(3, "M400"))) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok"]
    assert _text(_say(fw, framed(2, "M400"))) == ["ok"]  # a scheduled fault fires once


def test_corrupt_is_caught_by_the_checksum():
    fw = _fw("corrupt@1", seed=5)
    out = _text(_say(fw, framed(1, "G1 X10 Y10 F3000")))
    assert out[1:] == ["Resend: 1", "ok"]
    assert out[0].startswith("Error:")
    assert _text(_say(fw, framed(1, "G1 X10 Y10 F3000"))) == ["ok"]


@pytest.mark.parametrize(("spec", "expected"), [
    ("drop-ok@1", []),
    ("duplicate-ok@1", ["ok N1 P16 B3", "ok N1 P16 B3"]),
    ("busy@1:3", ["echo:busy: processing"] * 3 + ["ok N1 P16 B3"]),
])
def test_reply_faults(spec, expected):
    fw = _fw(spec, profile="marlin-advanced")
    assert _text(_say(fw, framed(1, "M400"))) == expected
    assert fw.executed == [(1, "M400")]


def test_corrupt_reply_flips_a_bit_of_the_ok():
    fw = _fw("corrupt-reply@1", seed=2)
    out = _text(_say(fw, framed(1, "M400")))
    assert len(out) == 1 and out[0] != "ok" and len(out[0]) == 2


def test_resend_storm():
    fw = _fw("resend-storm@1:3")
    for _ in range(3):
        assert _text(_say(fw, framed(1, "M400"))) == [
            "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
    assert _text(_say(fw, framed(1, "M400"))) == ["ok"]


def test_stall_and_disconnect_markers():
    fw = _fw("stall@1:2.5,disconnect@2")
    out = _say(fw, framed(1, "M400"))
    assert out[0] == Stall(2.5)
    out = _say(fw, framed(2, "M400"))
    assert out == [Disconnect()]
    assert fw.last_n == 0 and fw.stats.resets == 2


def test_disconnect_over_printsim_url_and_reconnect():
    with open_sim("faults=disconnect@2") as ser:
        ser.read(4096)
        ser.write(framed(1, "M400"))
        assert ser.read(100) == b"ok\n"
        ser.write(framed(2, "M400"))
        with pytest.raises(serial.SerialException, match="disconnected"):
            ser.read(100)
        ser.close()
        ser.open()  # the board was reset: banner, line numbers from 0
        assert ser.read(4096).splitlines()[0] == b"start"
        ser.write(framed(1, "M400"))
        assert ser.read(100) == b"ok\n"


def test_stall_over_printsim_url_delays_then_delivers():
    with open_sim("faults=stall@1:0.2", timeout=0) as ser:
        ser.read(4096)
        ser.write(framed(1, "M400"))
        assert ser.read(100) == b""  # stalled: nothing yet
        ser.timeout = 5
        assert ser.read(3) == b"ok\n"


RANDOM = "corrupt~0.05,drop-line~0.03,drop-ok~0.03,duplicate-ok~0.03,busy~0.05,resend-storm~0.01"


@pytest.mark.parametrize("seed", [1, 7, 12345])
def test_random_faults_are_reproducible_and_lose_nothing(seed):
    t1, ex1, f1 = _run(RANDOM, seed)
    t2, ex2, f2 = _run(RANDOM, seed)
    assert (t1, ex1, f1) == (t2, ex2, f2)
    assert f1, "the rates are high enough that faults must fire"
    streamed = [text for n, text in ex1 if n is not None and n >= 1]
    assert streamed == COMMANDS  # every line executed once, in order


def test_different_seeds_give_different_faults():
    assert _run(RANDOM, 1)[2] != _run(RANDOM, 2)[2]


def test_a_reset_drops_the_planned_moves_and_the_record_says_which():
    """Moves acknowledged into the planner but not started are lost with a reset, as on a
    real board: not deposited, and listed (log index, line number, text) in the record."""
    fw = _fw("disconnect@7", profile="marlin")
    cmds = ["M302 P1", "G92 X0 Y0 Z0.2 E0", *[f"G1 X{10 * k} Y0 E{k} F600" for k in (1, 2, 3, 4)]]
    for n, c in enumerate(cmds, 1):
        _say(fw, framed(n, c))
    assert _say(fw, framed(7, "M400")) == [Disconnect()]
    rec = fw.record()
    lost = rec.stats["lost_in_reset"]
    # the first move was running (its material is down); the three behind it were not
    assert [n for _, n, _ in lost] == [4, 5, 6]
    assert [t for _, _, t in lost] == cmds[3:]
    assert all(fw.executed[i][1] == t for i, _, t in lost)
    deposited = sum(lay.moves for lay in rec.layers)
    assert deposited == 1
