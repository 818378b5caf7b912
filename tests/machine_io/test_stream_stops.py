"""``printability stream`` always ends, and never leaves the printer heating: a damaged or
unanswered last line (the host waited for ever), and every signal that stops a process short
of SIGKILL (only Ctrl-C used to send the cancel sequence). Real entry point against the real
simulator (``printability simulate``), each wait bounded by a subprocess timeout so that a
hang fails the test instead of holding it."""

from __future__ import annotations

import fcntl
import json
import os
import re
import select
import signal
import subprocess
import sys
import termios
import threading
import time

import pytest
from _cli_helpers import CANCEL, PRINTABILITY, ROOT, Simulator, env

import simulators  # noqa: F401  (registers printsim://)
from machine_io import Host, HostConfig, parse_program
from machine_io.protocol import frame
from printability.errors import PrinterError
from simulators.faults import FaultInjector, FaultPlan

# Seven commands; the last is a long command (the host allows it the long timeout, 30 min,
# before it calls the printer silent), which is what turned a lost reply into a hang.
SEVEN = ["G28", "G90", "G1 X10 Y10 F3000", "G1 X20 Y10", "G1 X20 Y20", "G1 X10 Y20", "M400"]


def _corrupt_seed(n: int, command: str, *, number: bool) -> int:
    """A seed for which ``corrupt@n`` damages ``N<n> <command>`` in its line number (another
    number: the firmware refuses it as out of sequence, which the host took for a stale
    refusal and waited on) or, with ``number`` False, elsewhere (a checksum mismatch)."""
    line = frame(n, command)[:-1]
    for seed in range(1000):
        damaged = FaultInjector(FaultPlan.parse(f"corrupt@{n}", seed=seed)).corrupt(line)
        m = re.match(rb"N(\d+) ", damaged)
        if m and (int(m.group(1)) != n) == number:
            return seed
    raise AssertionError("no such seed")


def _expected(report: dict) -> list[str]:
    out = list(SEVEN)
    for at, cmds in reversed(report["injected"]):
        out[at:at] = cmds
    return out


@pytest.mark.parametrize("fault", ["line-number", "checksum", "drop-ok"])
def test_a_damaged_or_unanswered_last_line_ends_the_stream(tmp_path, fault):
    gcode = tmp_path / "seven.gcode"
    gcode.write_text("\n".join(SEVEN) + "\n")
    faults = {"line-number": ("corrupt@7", _corrupt_seed(7, SEVEN[-1], number=True)),
              "checksum": ("corrupt@7", _corrupt_seed(7, SEVEN[-1], number=False)),
              "drop-ok": ("drop-ok@7", 0)}[fault]
    report = tmp_path / "report.json"
    with Simulator(tmp_path / "record.json", "--faults", faults[0],
                   "--seed", str(faults[1])) as sim:
        r = subprocess.run([*PRINTABILITY, "stream", str(gcode), "--port", sim.port,
                            "--no-progress", "--json", str(report)],
                           capture_output=True, text=True, timeout=60, cwd=ROOT, env=env())
    assert r.returncode == 0, r.stderr
    assert f"printed {gcode}: 7 of 7 commands" in r.stdout
    doc = json.loads(report.read_text())
    assert doc["completed"]
    assert sim.log() == _expected(doc)  # every line once, in order
    kind = faults[0].split("@")[0]
    assert [kind, 7] in json.loads(sim.record.read_text())["stats"]["faults"]  # it did fire


def _stream_bounded(url: str, commands: list[str], limit: float = 30.0, **config):
    """Stream in a thread; (report, executed numbered lines), or a failed test after
    ``limit`` seconds instead of a hung one."""
    p = parse_program("\n".join(commands).encode(), source="p.gcode")
    out: dict = {}

    def run() -> None:
        try:
            with Host(url, config=HostConfig(**{"banner_timeout": 0.5, **config})) as host:
                host.connect()
                out["report"] = host.stream(p)
                out["log"] = [t for n, t in host._port.simulator.firmware.executed
                              if n is not None and not t.startswith("M110")]
        except BaseException as exc:  # reported below
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(limit)
    assert not thread.is_alive(), f"the host did not end within {limit} s"
    if "error" in out:
        raise out["error"]
    return out["report"], out["log"]


def test_temperature_auto_reports_do_not_hide_a_lost_ok():
    """M155 makes the firmware report temperatures every second: those lines restarted the
    silence clock, so a lost ok was waited for for ever."""
    cmds = ["M155 S1", "G90", "G1 X10 Y10 F6000", "G1 X20 Y10", "G1 X20 Y20", "G1 X10 Y20",
            "G1 X10 Y10"]
    report, log = _stream_bounded("printsim://?clock=real&faults=drop-ok@7", cmds,
                                  reply_timeout=3.0)
    assert report.completed and report.timeouts == 1
    assert log[:7] == cmds


def test_a_long_command_lost_before_any_keepalive_is_sent_again():
    """The first line, a long command, is lost on the wire: nothing has told the host yet
    whether the firmware sends busy: keepalives, so it used to wait the long timeout (30
    min); it now retransmits once after a few keepalive intervals of silence."""
    report, log = _stream_bounded("printsim://?faults=drop-line@1", SEVEN, keepalive_timeout=1.0)
    assert report.completed and report.timeouts == 0
    assert log == _expected({"injected": report.injected})


def test_the_host_gives_up_on_a_printer_that_keeps_restarting():
    """A board in a boot loop (a reset at every line) ends in a clear error, not reconnects
    for ever."""
    p = parse_program("\n".join(SEVEN).encode(), source="seven.gcode")
    # From line 5 on (the connection's own queries are counted as lines 1-3), every new line
    # resets the board.
    faults = ",".join(f"disconnect@{n}" for n in range(5, 60))
    with Host(f"printsim://?faults={faults}",
              config=HostConfig(reply_timeout=0.3, banner_timeout=0.5, handshake_timeout=1.0,
                                reconnect_timeout=5.0, max_reconnects=3)) as host:
        host.connect()
        with pytest.raises(PrinterError, match=r"times in a row without a command being "
                                            r"acknowledged") as info:
            host.stream(p)
    assert "resetting in a loop" in str(info.value)


@pytest.fixture
def long_print(tmp_path):
    lines = ["M140 S60", "M104 S210", "G28", "M190 S60", "M109 S210", "G90", "M82", "G92 E0",
             "G1 Z0.2 F600"]
    lines += [f"G1 X{20 + i % 100} Y{20 + (i // 100) % 100} E{0.01 * (i + 1):.3f} F3000"
              for i in range(16000)]
    path = tmp_path / "long.gcode"
    path.write_text("; a long print\n" + "\n".join(lines) + "\n")
    return path, lines


def _wait_for_line(stream, pattern: str, limit: float) -> str:
    """Read ``stream`` (a pipe) until a line matches ``pattern``."""
    deadline = time.monotonic() + limit
    buf = ""
    fd = stream.fileno()
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.1)
        if not ready:
            continue
        chunk = os.read(fd, 65536).decode()
        if not chunk:
            break
        buf += chunk
        if re.search(pattern, buf):
            return buf
    raise AssertionError(f"{pattern!r} never came; got {buf!r}")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT,
                                    signal.SIGINT], ids=lambda s: signal.Signals(s).name)
def test_every_stop_signal_leaves_the_printer_safe(tmp_path, long_print, signum):
    gcode, lines = long_print
    with Simulator(tmp_path / "record.json") as sim:
        # Progress on with stderr piped: a plain line at each quarter tells that the print is
        # under way (commands acknowledged, the rest still to come).
        proc = subprocess.Popen([*PRINTABILITY, "stream", str(gcode), "--port", sim.port],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=ROOT, env=env())
        try:
            head = _wait_for_line(proc.stderr, r"long\.gcode: \d+ %", 60)
            proc.send_signal(signum)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        err = " ".join((head + err).split())
    got = sim.log()
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    assert proc.returncode == 1, err
    assert f"cancelled by {name}" in err and "Traceback" not in err, err
    assert out == ""
    # The printer ran a prefix of the file, each command once, then the cancel sequence:
    # heaters, fan and motors off.
    n = len(got) - len(CANCEL)
    assert 9 < n < len(lines), err
    assert got == [*lines[:n], *CANCEL]
    # The resume hint names the first command that did not run (file line n + 2: the comment).
    assert f"--resume-from {n + 2}" in err


def test_a_stop_during_a_heat_up_breaks_the_wait_and_cools_the_printer(tmp_path):
    """SIGTERM while the bed heats (M190, real time): M108 ends the wait through the
    firmware's emergency parser, then the cancel sequence runs; the file's later commands
    never do."""
    heat = ["M140 S100", "M104 S200", "M190 S100", "M109 S200", "G28", "G1 X10 Y10"]
    gcode = tmp_path / "heat.gcode"
    gcode.write_text("\n".join(heat) + "\n")
    with Simulator(tmp_path / "record.json", clock="real") as sim:
        proc = subprocess.Popen([*PRINTABILITY, "stream", str(gcode), "--port", sim.port],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=ROOT, env=env())
        try:
            head = _wait_for_line(proc.stderr, r"heat\.gcode: 33 %", 60)  # M190 under way
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    err = " ".join((head + err).split())
    assert proc.returncode == 1 and "cancelled by SIGTERM" in err, err
    assert sim.log() == [*heat[:3], *CANCEL]
    assert "--resume-from 4" in err


def test_closing_the_terminal_leaves_the_printer_safe(tmp_path, long_print):
    """The terminal goes away under a live progress bar: the host gets SIGHUP and every write
    to the terminal then fails; the cancel sequence must still reach the printer."""
    gcode, lines = long_print
    with Simulator(tmp_path / "record.json") as sim:
        master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, b"\x1e\x00\x64\x00\x00\x00\x00\x00")

        # In the child, after exec (no preexec_fn: not safe with threads): the pty becomes
        # the controlling terminal of its new session, then it runs the real entry point.
        adopt = ("import fcntl, os, sys, termios; fcntl.ioctl(0, termios.TIOCSCTTY, 0); "
                 "os.execv(sys.argv[1], sys.argv[1:])")
        cmd = [*PRINTABILITY, "stream", str(gcode), "--port", sim.port]
        proc = subprocess.Popen([sys.executable, "-c", adopt, *cmd], stdin=slave,
                                stdout=slave, stderr=slave, cwd=ROOT,
                                env=env(TERM="xterm-256color"), start_new_session=True)
        os.close(slave)
        try:
            screen = b""
            under_way = re.compile(rb"[1-9][\d,]{3,}/[\d,]+ lines")  # 1,000 commands or more
            deadline = time.monotonic() + 60
            while not under_way.search(screen) and time.monotonic() < deadline:
                if select.select([master], [], [], 0.1)[0]:
                    screen += os.read(master, 65536)
            assert under_way.search(screen), screen  # the bar is drawn, the print under way
            os.close(master)  # the terminal hangs up: SIGHUP, and writes fail from now on
            proc.wait(60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    got = sim.log()
    n = len(got) - len(CANCEL)
    assert 9 < n < len(lines)
    assert got == [*lines[:n], *CANCEL]
    assert proc.returncode == 1


def test_a_display_that_fails_does_not_leave_the_printer_heating():
    """Any exception that ends a stream (here a progress callback that raises) sends the
    cancel sequence before it propagates."""
    p = parse_program("\n".join(["M104 S210", *(f"G1 X{i % 50} Y5" for i in range(3000))])
                      .encode(), source="p.gcode")

    def broken(progress) -> None:
        if progress.done > 100:
            raise RuntimeError("the display broke")

    with Host("printsim://", config=HostConfig(reply_timeout=0.5)) as host:
        host.connect()
        with pytest.raises(RuntimeError, match="the display broke"):
            host.stream(p, on_progress=broken)
        fw = host._port.simulator.firmware
        got = [t for n, t in fw.executed if n is not None and not t.startswith("M110")]
    assert got[-len(CANCEL):] == CANCEL
    assert got[:-len(CANCEL)] == list(p.commands[:len(got) - len(CANCEL)])
