"""What a host that watches the printer's liveness needs from the simulator (issue #29):
M155 temperature reports on the wall clock while the host is silent under the simulated clock
(OctoPrint declared the printer dead 9.2 s after a print ended), and Marlin's answers to M113
(host keepalive interval) and M21 (mount the SD card)."""

from __future__ import annotations

import time

import pytest
import serial
from _sim_helpers import framed

from simulators import Firmware, Link, PtyServer, make_config


def _fw(**kw) -> Firmware:
    fw = Firmware(make_config(**kw))
    fw.connect()
    fw.take_output()
    return fw


def _say(fw: Firmware, data: bytes) -> list[str]:
    fw.receive(data)
    fw.run_sim()
    return b"".join(x for x in fw.take_output()
                    if isinstance(x, bytes)).decode("latin-1").splitlines()


def _lines(link: Link) -> list[str]:
    return link.read_available().decode("latin-1").splitlines()


def _reports(lines: list[str]) -> list[str]:
    return [s for s in lines if s.startswith(" T:") and "W:" not in s]


# ------------------------------------------------------------------ M155 on the wall clock


def test_autoreport_keeps_coming_on_the_wall_clock_while_the_host_is_silent():
    link = Link(make_config(profile="marlin-advanced", clock="sim"))
    link.connect()
    _lines(link)
    link.feed(framed(1, "M104 S200") + framed(2, "M155 S1"))
    assert [s.split(" P")[0] for s in _lines(link)] == ["ok N1", "ok N2"]
    sim_now = link.firmware.now
    seen: list[str] = []
    t0 = time.monotonic()
    while len(_reports(seen)) < 2 and time.monotonic() < t0 + 10:  # the host says nothing
        seen += _lines(link)
        time.sleep(0.02)
    elapsed = time.monotonic() - t0
    reports = _reports(seen)
    # one a second of wall time, the first a second after the host spoke
    assert len(reports) == 2 and elapsed >= 1.95, (elapsed, seen)
    assert all("/200.00" in r for r in reports)
    # the simulated clock stood still: the run stays reproducible
    assert link.firmware.now == sim_now
    # M155 S0 ends them
    link.feed(framed(3, "M155 S0"))
    assert [s.split(" P")[0] for s in _lines(link)] == ["ok N3"]
    time.sleep(1.2)
    assert _reports(_lines(link)) == []


def test_a_host_that_keeps_talking_gets_no_wall_clock_reports():
    """The reports on the wall clock come only after a silence of one interval: a host
    streaming a file sees the same bytes on every run."""
    link = Link(make_config(profile="marlin-advanced", clock="sim"))
    link.connect()
    _lines(link)
    link.feed(framed(1, "M155 S2"))
    seen = _lines(link)
    end = time.monotonic() + 2.5
    n = 2
    while time.monotonic() < end:
        link.feed(framed(n, "M105"))
        seen += _lines(link)
        n += 1
        time.sleep(0.3)
    assert _reports(seen) == [], seen


def test_no_wall_clock_reports_while_the_firmware_works_or_is_halted():
    fw = _fw()
    _say(fw, b"M155 S1\n")
    assert fw.idle_report()                 # idle, reports on: one report
    assert _reports([s for x in fw.take_output() if isinstance(x, bytes)
                     for s in x.decode().splitlines()])
    fw.receive(b"G4 S5\n")                  # queued, not yet run: the firmware is not idle
    assert not fw.idle_report()
    fw.run_sim()
    fw.take_output()
    assert fw.idle_report()
    _say(fw, b"M112\n")
    assert not fw.idle_report()


def test_octoprint_like_silence_over_the_pty():
    """A host on the pseudo-terminal turns auto-reports on and then says nothing: reports
    keep arriving (OctoPrint's 'no response' watchdog is fed)."""
    link = Link(make_config(profile="marlin", clock="sim"))
    with PtyServer(link) as srv, serial.Serial(srv.path, 115200, timeout=0.2) as ser:
        deadline = time.monotonic() + 10
        buf = b""
        while b"start" not in buf and time.monotonic() < deadline:
            buf += ser.read(4096)
        ser.write(framed(1, "M155 S1"))
        got = b""
        end = time.monotonic() + 10
        while len(_reports(got.decode("latin-1").splitlines())) < 2 \
                and time.monotonic() < end:
            got += ser.read(4096)
    lines = got.decode("latin-1").splitlines()
    assert lines[0] == "ok"
    assert len(_reports(lines)) >= 2, lines


# ------------------------------------------------------------------ M113, M21


def test_m113_reports_and_sets_the_keepalive_interval():
    fw = _fw()
    assert _say(fw, b"M113\n") == ["echo:M113 S2", "ok"]
    assert _say(fw, b"M113 S5\nM113\n") == ["ok", "echo:M113 S5", "ok"]
    out = _say(fw, b"G4 S21\n")
    assert out.count("echo:busy: processing") == 4  # at 5, 10, 15 and 20 s
    # Marlin caps the interval at 60 s; S0 turns the keepalive off
    assert _say(fw, b"M113 S600\nM113\n") == ["ok", "echo:M113 S60", "ok"]
    assert _say(fw, b"M113 S0\nG4 S30\nM113\n") == ["ok", "ok", "echo:M113 S0", "ok"]
    # a reset brings the profile's interval back
    fw.connect()
    fw.take_output()
    assert _say(fw, b"M113\n") == ["echo:M113 S2", "ok"]


def test_m21_answers_as_marlin_with_an_empty_card_slot():
    fw = _fw()
    assert _say(fw, b"M21\n") == ["echo:No SD card", "ok"]
    caps = _say(fw, b"M115\n")
    assert "Cap:SDCARD:1" in caps
    assert fw.stats.unknown == 0


@pytest.mark.parametrize("code", ["M113 S2", "M21"])
def test_klipper_takes_m113_and_m21_silently(code):
    fw = _fw(profile="klipper")
    assert _say(fw, code.encode() + b"\n") == ["ok"]
    assert fw.stats.unknown == 0
