"""The host's state machine against a tiny scripted Marlin (faults at chosen lines).

These pin the protocol logic deterministically; the fault-injecting simulator
tests (test_host_simulator.py) check the same promises against the real thing.
"""

from __future__ import annotations

import json
import threading
from types import SimpleNamespace

import pytest
from _fake_marlin import FakeMarlin

from machine_io import Host, HostConfig, Transcript, executed_as_streamed, parse_program
from printability.errors import InputError, PrinterError

FAST = dict(reply_timeout=0.4, banner_timeout=0.3, handshake_timeout=0.5, resend_ok_timeout=0.2,
            reconnect_timeout=0)
QUERIES = ("M115", "M114", "M105")


def program(n: int = 300, rotary: bool = False):
    lines = [f"G1 X{i % 100}.5 Y{i % 37} {'C' + str(i % 360) + ' ' if rotary else ''}E{i}.25"
             for i in range(n)]
    return parse_program(("G28 ; home\n\n" + "\n".join(lines) + "\n").encode(), source="t.gcode")


def printed(fw: FakeMarlin) -> list[str]:
    """What the firmware executed from the file: host queries (M115/M114, the M105 barrier)
    left out."""
    return [c for c in fw.executed if not c.startswith(QUERIES)]


FAULTS = {
    "none": {},
    "corrupt": {5: ["corrupt"], 6: ["corrupt"], 150: ["corrupt"]},
    "drop-line": {20: ["drop"], 21: ["drop"], 299: ["drop"]},
    "drop-ok": {30: ["drop_ok"], 31: ["drop_ok"], 302: ["drop_ok"]},
    "dup-ok": {40: ["dup_ok"], 41: ["dup_ok"], 200: ["dup_ok"]},
    "busy": {50: ["busy"], 51: ["busy"]},
    "all": {5: ["corrupt"], 20: ["drop"], 30: ["drop_ok"], 40: ["dup_ok"], 50: ["busy"],
            60: ["corrupt", "dup_ok"], 61: ["drop"], 62: ["drop_ok"]},
}


@pytest.mark.parametrize("advanced", [False, True], ids=["plain-ok", "advanced-ok"])
@pytest.mark.parametrize("faults", list(FAULTS), ids=list(FAULTS))
def test_every_command_runs_once_in_order(advanced, faults):
    p = program()
    with FakeMarlin(advanced_ok=advanced, faults=FAULTS[faults]) as fw, \
            Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(p)
    assert printed(fw) == list(p.commands)
    assert report.completed and report.acknowledged == len(p) and report.stopped is None
    assert report.mode == ("send-ahead" if advanced else "ping-pong")
    if faults in ("corrupt", "drop-line") and not advanced:
        assert report.resends + report.timeouts >= 3


def test_a_refused_handshake_after_a_restart_is_asked_again():
    """The board resets on line 150 and the host's ``M110 N150`` then arrives damaged: the
    ``ok`` behind the firmware's Resend is not the handshake's, so the host asks again
    (taking it once made every later line draw 'Resend: 1' and the print stall).
    Ping-pong, so that line 150 is the last one sent when the board resets."""
    p = program(300)
    cfg = HostConfig(**{**FAST, "reconnect_timeout": 5.0})
    with FakeMarlin(faults={150: ["restart", "corrupt"]}) as fw, \
            Host(fw.path, config=cfg) as host:
        host.connect()
        report = host.stream(p)
    assert report.completed and report.reconnects == 1
    # printed() leaves out the M105 end barrier: so does the report checked against it
    seen = SimpleNamespace(injected=[i for i in report.injected if i[1] != ("M105",)],
                           in_doubt=report.in_doubt)
    assert executed_as_streamed(printed(fw), list(p.commands), seen)
    assert sum(1 for line in fw.received if b"M110 N150" in line) == 2


def test_resend_without_ok_is_handled_by_the_timer():
    p = program(50)
    with FakeMarlin(ok_after_resend=False, faults={5: ["corrupt"], 9: ["corrupt"]}) as fw, \
            Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(p)
    assert printed(fw) == list(p.commands) and report.resends == 2


def test_stale_resends_in_send_ahead_are_ignored():
    p = program(100)
    with FakeMarlin(advanced_ok=True, buffer_slots=8, faults={10: ["corrupt"]}) as fw, \
            Host(fw.path, config=HostConfig(mode="send-ahead", **FAST)) as host:
        host.connect()
        report = host.stream(p)
    assert printed(fw) == list(p.commands)
    # One line was resent; every further request for it (lines already in flight arrive out
    # of order and each draws one, as many as timing allows) is recognised as stale.
    assert report.resends == 1
    assert report.stale_resends == fw.resend_requests - 1


def test_too_many_resends_of_one_line_stop_with_the_place():
    p = program(40)
    with FakeMarlin(always_corrupt=frozenset({12})) as fw, \
            Host(fw.path, config=HostConfig(max_resends=3, **FAST)) as host:
        host.connect()
        with pytest.raises(PrinterError) as e:
            host.stream(p)
    msg = str(e.value)
    assert "asked for line 12 4 times in a row (limit 3)" in msg
    assert "The last command acknowledged was command 11 of 41" in msg
    assert "--resume-from 13" in msg
    assert printed(fw) == list(p.commands[:11])
    assert e.value.report.acknowledged == 11


def test_printer_that_never_answers_is_a_clear_error_and_nothing_is_sent():
    with FakeMarlin(answer=False, banner=False) as fw, \
            Host(fw.path, config=HostConfig(**FAST)) as host:
        with pytest.raises(PrinterError, match=r"did not answer.*nothing of the file was sent"):
            host.connect()
        assert all(b"M110" in line for line in fw.received)


def test_printer_that_stops_answering_mid_print_says_where():
    p = program(100)
    with FakeMarlin(faults={41: ["silent"]}) as fw, \
            Host(fw.path, config=HostConfig(max_timeouts=2, **FAST)) as host:
        host.connect()
        with pytest.raises(PrinterError) as e:
            host.stream(p)
    msg = str(e.value)
    assert "stopped answering" in msg
    assert "The last command acknowledged was command 40 of 101" in msg
    assert "--resume-from 42" in msg  # file line 42 holds command 41
    assert printed(fw) == list(p.commands[:40])


@pytest.mark.parametrize("axes, ok", [("XYZ", False), ("XYZC", True)])
def test_rotary_gcode_needs_a_rotary_axis(axes, ok):
    p = program(20, rotary=True)
    with FakeMarlin(axes=axes) as fw, Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        if ok:
            assert host.stream(p).completed
            assert printed(fw) == list(p.commands)
        else:
            with pytest.raises(PrinterError, match=r"rotary axis C.*reports the axes X, Y, Z; "
                                                   r"nothing was sent"):
                host.stream(p)
            assert printed(fw) == []


@pytest.mark.parametrize("policy", ["stop", "cancel", "ignore"])
def test_firmware_errors_follow_the_policy(policy):
    p = program(60)
    with FakeMarlin(faults={20: ["error"]}) as fw, \
            Host(fw.path, config=HostConfig(error_policy=policy, **FAST)) as host:
        host.connect()
        if policy == "ignore":
            report = host.stream(p)
            assert report.completed and printed(fw) == list(p.commands)
            assert any("Heater failure" in e for e in report.events)
            return
        with pytest.raises(PrinterError, match=f"Heater failure.*policy '{policy}'") as e:
            host.stream(p)
    done = e.value.report.acknowledged
    assert 19 <= done < len(p)  # the error came before the ok of line 20
    if policy == "stop":
        assert any(line == b"M112" for line in fw.received)
        assert printed(fw)[:done] == list(p.commands[:done])
    else:
        assert printed(fw) == [*p.commands[:done], "M104 S0", "M140 S0", "M107", "M84"]


def test_cancel_finishes_lines_in_flight_then_sends_the_cancel_sequence():
    p = program(20000)  # long enough to still be streaming at the first progress report
    with FakeMarlin() as fw, Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        seen = []

        def on_progress(pr):
            seen.append(pr.done)
            if pr.done > 200:
                host.cancel()

        report = host.stream(p, on_progress=on_progress)
    assert not report.completed and report.stopped == "cancelled"
    n = report.acknowledged
    assert 200 < n < len(p)
    assert printed(fw) == [*p.commands[:n], "M104 S0", "M140 S0", "M107", "M84"]
    assert report.injected[-1] == (n, ("M104 S0", "M140 S0", "M107", "M84"))


def test_pause_and_resume_lose_nothing():
    p = program(20000)  # still streaming at the first progress report
    cfg = HostConfig(pause_gcode=("G91", "G1 Z5", "G90"), **FAST)
    with FakeMarlin() as fw, Host(fw.path, config=cfg) as host:
        host.connect()
        states = []

        def on_progress(pr):
            states.append(pr.state)
            if pr.done > 100 and not states.count("paused") and not host.paused:
                host.pause()
                threading.Timer(0.3, host.resume).start()

        report = host.stream(p, on_progress=on_progress)
    assert report.completed and "paused" in states
    (at, pause_cmds), (at2, restore) = report.injected[:2]
    assert at == at2 and pause_cmds == ("G91", "G1 Z5", "G90")
    expected = [*p.commands[:at], *pause_cmds, *restore, *p.commands[at:]]
    assert printed(fw) == expected


def test_printer_pause_and_resume_host_actions():
    p = program(5000)
    with FakeMarlin() as fw, Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        fired = []

        def on_progress(pr):
            if pr.state == "streaming" and pr.done > 50 and not fired:
                fired.append(1)
                fw._send("//action:pause")
                threading.Timer(0.3, lambda: fw._send("//action:resume")).start()

        report = host.stream(p, on_progress=on_progress)
    assert report.completed and printed(fw) == list(p.commands)
    assert [e for e in report.events if "asked to" in e] == [
        "the printer asked to pause", "the printer asked to resume"]


def test_start_index_and_restore_resume_a_print():
    p = parse_program(b"M140 S60\nM104 S200\nG28\nG1 X5 Y5 Z0.2 C30 E1 F1200\nG1 X6 E2\n"
                      b"G1 X7 E3\n", source="r.gcode")
    with FakeMarlin(axes="XYZC") as fw, Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(p, start=5, restore=True)
    restore = report.injected[0][1]
    assert printed(fw) == [*restore, "G1 X7 E3"]
    assert "G92 Z0.2000 C30.0000" in restore and "G92 E2.00000" in restore
    assert "M109 S200" in restore and "G28 X Y" in restore


def test_transcript_records_both_directions(tmp_path):
    p = program(10)
    log = tmp_path / "serial.log"
    with FakeMarlin() as fw, Host(fw.path, config=HostConfig(**FAST),
                                  transcript=Transcript(log)) as host:
        host.connect()
        host.stream(p)
    text = log.read_text()
    assert "Send: N1 G28*" in text and "Recv: ok" in text and "Recv: FIRMWARE_NAME:" in text


def test_config_is_validated():
    with pytest.raises(InputError, match="stream mode"):
        HostConfig(mode="fast")
    with pytest.raises(InputError, match="reply_timeout"):
        HostConfig(reply_timeout=-1)


def test_resume_file_names_the_next_command(tmp_path):
    p = program(200)
    state = tmp_path / "resume.json"
    with FakeMarlin(faults={120: ["silent"]}) as fw, \
            Host(fw.path, config=HostConfig(max_timeouts=1, **FAST)) as host:
        host.connect()
        with pytest.raises(PrinterError):
            host.stream(p, resume_file=state)
    doc = json.loads(state.read_text())
    assert doc["next_command"] == 119 and doc["total"] == len(p)
    assert doc["next_line"] == p.source_lines[119] == 121
    assert printed(fw) == list(p.commands[:119])
