"""The host against the virtual printer with injected faults: every command of the file runs
exactly once, in order — the simulator's executed log equals the file (plus what the host
says it injected: restore sequences after a restart, the M105 end barrier, handshake queries).

The default run streams a few thousand lines over the in-process ``printsim://`` port and
the pty and TCP transports; ``-m slow`` runs the 100 000-line print.
"""

from __future__ import annotations

import random

import pytest

import simulators
from machine_io import Host, HostConfig, Program, StreamReport, executed_as_streamed, parse_program
from printability.errors import PrinterError
from simulators.transports import Link, PtyServer, TcpServer

FAST = dict(reply_timeout=0.3, banner_timeout=0.5, handshake_timeout=1.0, confirm_timeout=0.2,
            resend_ok_timeout=0.3, reconnect_timeout=10.0)


def gcode(n: int, *, rotary: bool = True, seed: int = 7) -> Program:
    """A print of ``n`` lines: heat, home, then extrusion moves turning the C axis."""
    rng = random.Random(seed)
    lines = ["M140 S60", "M104 S210", "G28", "M190 S60", "M109 S210", "G90", "M82", "G92 E0",
             "G1 Z0.2 F600"]
    e = 0.0
    for i in range(n - len(lines)):
        e += rng.uniform(0.005, 0.05)
        c = f" C{rng.uniform(-90, 90):.2f}" if rotary and i % 3 == 0 else ""
        lines.append(f"G1 X{rng.uniform(20, 180):.3f} Y{rng.uniform(20, 180):.3f}{c} "
                     f"E{e:.5f} F{rng.choice((1800, 2400, 3000))}")
    return parse_program("\n".join(lines).encode(), source="sim.gcode")


def executed(firmware) -> list[str]:
    """The numbered lines the firmware ran, handshakes left out (the host's unnumbered
    queries may be damaged on a faulty wire and then run as unknown commands)."""
    return [t for n, t in firmware.executed if n is not None and not t.startswith("M110")]


def expected(program: Program, report: StreamReport) -> list[str]:
    """The file with the host's injected commands where it says it put them."""
    out = list(program.commands)
    for at, cmds in reversed(report.injected):
        out[at:at] = cmds
    return out


def stream(url: str, program: Program, **cfg) -> tuple[StreamReport, object]:
    with Host(url, config=HostConfig(**{**FAST, **cfg})) as host:
        host.connect()
        report = host.stream(program)
        return report, host._port.simulator.firmware


FAULTS = [
    "corrupt~0.01",
    "drop-ok~0.005",
    "duplicate-ok~0.01",
    "busy~0.01",
    "drop-line~0.003",
    "corrupt-reply~0.005",
    "stall@900:0.8",
    "resend-storm@700:4",
    "disconnect@1200",
    "corrupt~0.01,drop-ok~0.003,busy~0.01,stall@1500:0.5,disconnect@1800,duplicate-ok~0.005",
]


@pytest.mark.parametrize("profile", ["marlin", "marlin-advanced"])
@pytest.mark.parametrize("faults", FAULTS)
def test_every_command_runs_once_in_order(profile, faults):
    p = gcode(2500)
    report, fw = stream(f"printsim://?profile={profile}&faults={faults}&seed=3", p)
    assert report.completed, report.stopped
    assert executed_as_streamed(executed(fw), list(p.commands), report)
    assert fw.stats.faults, "the faults must actually fire"
    if "disconnect" in faults:
        assert report.reconnects == 1
        (_at, restore), = [(a, c) for a, c in report.injected if c != ("M105",)]
        assert "G28 X Y" in restore and "M109 S210" in restore and any(
            c.startswith("G92 Z0.2000 C") for c in restore)
    assert report.mode == ("send-ahead" if profile == "marlin-advanced" else "ping-pong")


def test_a_restart_with_an_unacknowledged_line_is_reported_in_doubt():
    """Send-ahead: line 699's ok is lost and line 700 resets the board before the host
    notices. 699 was queued before the reset and is sent again after it: it runs twice,
    and only the report's ``in_doubt`` makes that visible (nothing on the wire can)."""
    p = gcode(1000)
    report, fw = stream("printsim://?profile=marlin-advanced&faults=drop-ok@699,disconnect@700",
                        p)
    assert report.completed and report.reconnects == 1
    (at, count), = report.in_doubt
    assert report.injected[0][0] == at and 1 <= count <= 3
    got = executed(fw)
    assert got != expected(p, report)  # one command ran before the restart and after it
    assert executed_as_streamed(got, list(p.commands), report)
    assert "in_doubt" in report.to_json()


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_transports_with_faults_and_a_disconnect(transport):
    p = gcode(1500)
    link = Link(simulators.make_config(profile="marlin-advanced",
                                       faults="corrupt~0.01,drop-ok~0.005,disconnect@700",
                                       seed=5))
    server = PtyServer(link) if transport == "pty" else TcpServer(link)
    with server:
        port = server.path if transport == "pty" else server.url
        with Host(port, config=HostConfig(**FAST)) as host:
            host.connect()
            report = host.stream(p)
        with link.lock:
            got = executed(link.firmware)
    assert report.completed and report.reconnects == 1
    assert executed_as_streamed(got, list(p.commands), report)


def test_send_ahead_never_overflows_the_receive_buffer():
    # A board without flow control loses bytes beyond a full 128-byte ring: any overflow
    # would show as dropped bytes and checksum errors.
    p = gcode(3000)
    url = "printsim://?profile=marlin-advanced&fw.rx_overflow_drops=true&fw.planner_buffer=4"
    report, fw = stream(url, p, mode="send-ahead")
    assert report.completed and report.mode == "send-ahead"
    assert fw.stats.bytes_dropped == 0 and report.resends == 0
    assert executed_as_streamed(executed(fw), list(p.commands), report)


def test_firmware_without_ok_after_resend():
    p = gcode(1500)
    report, fw = stream("printsim://?profile=marlin&fw.ok_after_resend=false&faults=corrupt~0.01"
                        "&seed=2", p)
    assert report.completed and report.resends > 5
    assert executed_as_streamed(executed(fw), list(p.commands), report)


def test_resend_ratio_and_temperatures_are_reported():
    p = gcode(1000)
    temps = []
    with Host("printsim://?profile=marlin&faults=corrupt~0.02&seed=4",
              config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(p, on_progress=lambda pr: temps.append(pr.temperatures))
    assert 0 < report.resend_ratio < 0.1
    assert report.resend_ratio == report.resends / report.lines_sent
    hot = [t for t in temps if t.get("T", (0, 0))[1] == 210.0]
    assert hot, "the M109 wait reports temperatures, the host shows them"


def test_rotary_gcode_is_refused_by_a_printer_without_the_axis():
    p = gcode(200)
    with Host("printsim://?machine=xy", config=HostConfig(**FAST)) as host:
        host.connect()
        assert host.firmware.has_axis("C") is False
        with pytest.raises(PrinterError, match=r"rotary axis C.*nothing was sent"):
            host.stream(p)
        assert executed(host._port.simulator.firmware) == []


def test_emergency_stop_when_the_printer_halts():
    # M112 in the file halts the firmware: the host stops and says where.
    p = parse_program(b"G28\nG1 X10 Y10 F3000\nM112\nG1 X20 Y20\n", source="halt.gcode")
    with Host("printsim://", config=HostConfig(**FAST)) as host:
        host.connect()
        with pytest.raises(PrinterError, match=r"printer halted.*The last command acknowledged "
                                               r"was command 2 of 4"):
            host.stream(p)


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["marlin", "marlin-advanced"])
def test_100k_lines_with_faults_lose_nothing(profile):
    p = gcode(100_000)
    faults = ("corrupt~0.01,drop-ok~0.001,busy~0.005,stall@30000:1,stall@61000:0.5,"
              "disconnect@50000,duplicate-ok~0.001")
    report, fw = stream(f"printsim://?profile={profile}&faults={faults}&seed=11", p,
                        reply_timeout=0.2)
    assert report.completed and report.acknowledged == len(p) == 100_000
    assert executed_as_streamed(executed(fw), list(p.commands), report)
    kinds = {k for k, _ in fw.stats.faults}
    assert {"corrupt", "drop-ok", "busy", "stall", "disconnect"} <= kinds
