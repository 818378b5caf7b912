"""Transports: the pty and TCP servers with pyserial, the simulate CLI, and a real
third-party host (Printrun's printcore) streaming a real slicer file over the pty."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial
from _sim_helpers import MiniHost, file_commands, framed

from simulators import Link, PtyServer, TcpServer, make_config

ROOT = Path(__file__).resolve().parents[2]
CURA = "gcode/cura_5.9.1_marlin.gcode"


def _readlines_until(ser, pred, *, limit: float = 10.0) -> list[str]:
    """Read lines until pred(line) holds (bounded by `limit` seconds)."""
    out: list[str] = []
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        raw = ser.readline()
        if not raw:
            continue
        line = raw.decode("latin-1").rstrip("\n")
        out.append(line)
        if pred(line):
            return out
    raise AssertionError(f"no matching line within {limit} s; got {out!r}")


@pytest.mark.parametrize("clock", ["sim", "real"])
def test_pty_banner_commands_and_reset_on_open(clock):
    link = Link(make_config(profile="marlin-advanced", clock=clock))
    with PtyServer(link) as srv:
        with serial.Serial(srv.path, 115200, timeout=0.5) as ser:
            assert _readlines_until(ser, lambda s: s == "start")[-1] == "start"
            ser.write(framed(1, "M115"))
            lines = _readlines_until(ser, lambda s: s.startswith("ok"))
            assert "Cap:ROTARY_AXIS:C" in lines and lines[-1] == "ok N1 P16 B3"
            ser.write(framed(2, "G1 X10 Y10 F3000"))
            ser.write(framed(3, "M400"))
            _readlines_until(ser, lambda s: s.startswith("ok N3"))
        # Opening the port again resets the board (DTR), as an Arduino-based printer does.
        deadline = time.monotonic() + 10
        while srv.connected and time.monotonic() < deadline:
            time.sleep(0.01)  # the server notices the close
        with serial.Serial(srv.path, 115200, timeout=0.5) as ser:
            _readlines_until(ser, lambda s: s == "start")
            ser.write(framed(1, "M114"))
            pos = _readlines_until(ser, lambda s: s.startswith("X:"))[-1]
            assert pos.startswith("X:0.00 Y:0.00")
    assert link.firmware.stats.resets >= 2


def test_real_clock_answers_no_sooner_than_the_wire_carries_line_and_ok():
    """Under the real clock the firmware runs ahead to the line's arrival and its ``ok``
    is held until it has crossed the return wire: never early, whatever Python costs."""
    baud = 9600  # slow, so the bound is far above scheduling noise
    link = Link(make_config(profile="marlin", clock="real", baud=baud))
    link.connect()
    banner = b""
    deadline = time.monotonic() + 5
    while not banner.endswith(link.firmware.fw.banner[-1].encode() + b"\n"):
        assert time.monotonic() < deadline, banner
        time.sleep(0.005)
        banner += link.read_available()
    line = framed(1, "M400")
    t0 = time.monotonic()
    link.feed(line)
    assert link.firmware.executed and link.read_available() == b""  # run ahead, held back
    got = b""
    while not got.endswith(b"\n") and time.monotonic() < t0 + 5:
        time.sleep(max(link.wait_time(), 0.0002))
        got += link.read_available()
    assert got == b"ok\n"
    assert time.monotonic() - t0 >= (len(line) + len(got)) * 10 / baud


def test_a_full_receive_ring_is_polled_not_spun():
    """A sender without flow control fills the receive ring behind a full planner: input is
    then due but cannot move, and the servers must not spin on it (they did, a whole core)."""
    link = Link(make_config(profile="marlin", machine="xy", clock="real", baud=250000))
    link.connect()
    moves = b"".join(f"G1 X{10 + (i % 2) * 100} Y10 E0.5 F600\n".encode() for i in range(60))
    link.feed(b"M302 P1\nG90\n" + moves)
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        time.sleep(0.02)
        link.read_available()
        if not link._held and link.firmware.next_event() <= link._now():
            break
    assert link.firmware.next_event() <= link._now()  # input due, the ring full
    assert link.wait_time() >= 0.0009


def test_tcp_socket_url_and_disconnect_fault():
    link = Link(make_config(faults="disconnect@3"))
    with TcpServer(link) as srv:
        assert srv.url.startswith("socket://127.0.0.1:")
        ser = serial.serial_for_url(srv.url, timeout=0.5)
        _readlines_until(ser, lambda s: s == "start")
        ser.write(framed(1, "M105"))
        assert _readlines_until(ser, lambda s: s.startswith("ok"))[-1].startswith("ok T:")
        ser.write(framed(2, "M400"))
        _readlines_until(ser, lambda s: s == "ok")
        ser.write(framed(3, "M400"))
        with pytest.raises(serial.SerialException):
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                ser.read(100)  # the server closed the connection
        ser.close()
        ser = serial.serial_for_url(srv.url, timeout=0.5)
        _readlines_until(ser, lambda s: s == "start")
        ser.write(framed(1, "M400"))
        _readlines_until(ser, lambda s: s == "ok")
        ser.close()
    assert [n for n, _ in link.firmware.executed] == [1, 2, 1]


def _printcore_stream(path: Path, lines: list[str], *, limit: float) -> Link:
    printcore = pytest.importorskip("printrun.printcore").printcore
    gcoder = pytest.importorskip("printrun.gcoder")
    link = Link(make_config(profile="marlin", clock="sim"))
    with PtyServer(link) as srv:
        p = printcore()
        try:
            p.connect(srv.path, 115200)
            deadline = time.monotonic() + limit
            while not p.online and time.monotonic() < deadline:
                time.sleep(0.02)
            assert p.online, "printcore never saw the printer answer"
            p.startprint(gcoder.LightGCode(lines))
            while p.printing and time.monotonic() < deadline:
                time.sleep(0.05)
            assert not p.printing, f"printcore did not finish within {limit} s"
        finally:
            p.disconnect()
    return link


def _check_printcore_log(link: Link, path: Path, n_lines: int | None) -> None:
    expected = file_commands(path, limit=n_lines)
    # printcore numbers the file's lines from 0 after 'N-1 M110 N-1'; its own M105 polls
    # while connecting carry no number.
    streamed = [t for n, t in link.firmware.executed if n is not None and n >= 0]
    assert streamed == expected
    assert all(t == "M105" for n, t in link.firmware.executed if n is None)


def test_printcore_streams_a_real_file_over_the_pty(shared_data):
    path = shared_data / CURA
    lines = path.read_text().splitlines()[:3000]
    link = _printcore_stream(path, lines, limit=120)
    _check_printcore_log(link, path, 3000)
    assert link.firmware.stats.unknown == 1  # Cura's 'START_PRINT ...' Klipper macro line


@pytest.mark.slow
def test_printcore_streams_a_whole_file_over_the_pty(shared_data):
    path = shared_data / CURA
    link = _printcore_stream(path, path.read_text().splitlines(), limit=900)
    _check_printcore_log(link, path, None)
    rec = link.firmware.record()
    # The file heats with a Klipper macro (START_PRINT EXTRUDER_TEMP=200) that Marlin does not
    # know, and only sends M104 S200 after layer 0: Marlin refuses the cold extrusion of the
    # 0.2 mm layer and prints the other 24 of the file's 25 layers.
    assert link.firmware.stats.cold_extrusions > 0
    assert len(rec.layers) == 24 and rec.layers[0].z == pytest.approx(0.4)


# ------------------------------------------------------------------ the CLI


def _start_cli(*args: str, env_extra: dict | None = None) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1", **(env_extra or {}))
    proc = subprocess.Popen([sys.executable, "-m", "printability", "simulate", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, env=env)
    first = proc.stdout.readline().strip()
    return proc, first


def _stop_cli(proc: subprocess.Popen) -> tuple[int, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        raise
    return proc.returncode, err


@pytest.mark.parametrize("transport", [["--pty"], ["--tcp", "0"]])
def test_simulate_cli_prints_the_port_and_writes_the_record(tmp_path, transport):
    rec = tmp_path / "record.json"
    proc, port = _start_cli(*transport, "--clock", "sim", "--profile", "marlin-advanced",
                            "--nozzle", "ellipse:major=0.8,minor=0.3", "--record", str(rec),
                            "--duration", "120")
    try:
        assert port.startswith("/dev/") if transport == ["--pty"] else \
            port.startswith("socket://127.0.0.1:")
        ser = serial.serial_for_url(port, timeout=0.5)
        try:
            _readlines_until(ser, lambda s: s == "start")

            class Blocking:  # MiniHost reads what is there: wait until the link is quiet
                def __init__(self, s):
                    self.s = s
                    s.timeout = 0.05

                def write(self, data):
                    self.s.write(data)

                def read(self, n):
                    buf = b""
                    while chunk := self.s.read(4096):
                        buf += chunk
                    return buf

            cmds = ["M302 P1", "G28", "G1 Z0.2 F600", "G1 X10 Y10 C0 F3000",
                    "G1 X20 Y10 C90 E1", "M400"]
            MiniHost(Blocking(ser)).stream(cmds)
        finally:
            ser.close()
    finally:
        code, err = _stop_cli(proc)
    assert code == 0, err
    assert "record written" in err
    doc = json.loads(rec.read_text())
    assert [t for n, t in doc["log"] if n is not None and n >= 1] == cmds
    assert doc["layers"][0]["z"] == pytest.approx(0.2)
    assert doc["stats"]["nozzle"] == "ellipse:major=0.8,minor=0.3"


@pytest.mark.parametrize(("args", "message"), [
    (["--profile", "repetier"], "unknown firmware profile"),
    (["--faults", "drop-ok"], "KIND@LINE"),
    (["--pty", "--tcp", "0"], "choose one transport"),
    (["--fw", "planner_buffer=0"], "planner_buffer must be a positive integer"),
    (["--nozzle", "circle:d=-1"], "positive length"),
])
def test_simulate_cli_errors(args, message):
    proc = subprocess.run([sys.executable, "-m", "printability", "simulate", *args,
                           "--duration", "1"], capture_output=True, text=True, cwd=ROOT,
                          timeout=60)
    assert proc.returncode == 1
    assert message in " ".join(proc.stderr.split())
    assert proc.stdout == ""


def test_simulate_help_runs():
    from printability.app.cli.main import main

    assert main(["simulate", "--help"]) == 0


def test_simulate_cli_writes_the_record_on_sigusr1(tmp_path):
    rec = tmp_path / "now.json"
    proc, port = _start_cli("--tcp", "0", "--clock", "sim", "--record", str(rec),
                            "--duration", "120")
    try:
        ser = serial.serial_for_url(port, timeout=0.5)
        _readlines_until(ser, lambda s: s == "start")
        ser.write(framed(1, "M400"))
        _readlines_until(ser, lambda s: s == "ok")
        proc.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + 20
        while not rec.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert json.loads(rec.read_text())["log"] == [[1, "M400"]]
        assert proc.poll() is None  # still serving
        ser.close()
    finally:
        code, err = _stop_cli(proc)
    assert code == 0, err


def test_simulate_cli_reports_mmc_violations_against_a_target(tmp_path):
    target = tmp_path / "part.wkt"
    target.write_text("POLYGON ((50 50, 70 50, 70 70, 50 70, 50 50))\n")
    rec = tmp_path / "rec.json"
    proc, port = _start_cli("--tcp", "0", "--clock", "sim", "--record", str(rec), "--target",
                            str(target), "--duration", "120")
    try:
        ser = serial.serial_for_url(port, timeout=0.5)
        _readlines_until(ser, lambda s: s == "start")
        cmds = ["M302 P1", "G28", "G1 Z0.2 F600", "G1 X55 Y55 F3000", "G1 X65 Y55 E1",
                "G1 X75 Y65 E2", "M400"]
        for i, c in enumerate(cmds, 1):
            ser.write(framed(i, c))
            _readlines_until(ser, lambda s: s.startswith("ok"))
        ser.close()
    finally:
        code, err = _stop_cli(proc)
    assert code == 0, err
    doc = json.loads(rec.read_text())
    (v,) = doc["violations"]
    assert v["first_line"] == 6 and v["first_text"] == "G1 X75 Y65 E2"
    assert v["bbox"][2] == pytest.approx(75.2, abs=0.01)
    assert doc["target"] == str(target)


def test_real_clock_printsim_with_baud_pacing_and_autoreport():
    """Wall-clock mode in-process: paced wire, moves executed, M155 reports while idle."""
    with serial.serial_for_url("printsim://?clock=real&baud=115200&profile=marlin-advanced"
                               "&fw.homing_time=0.5",
                               timeout=0.5) as ser:
        _readlines_until(ser, lambda s: s == "start")
        cmds = ["M302 P1", "G28", "G1 X5 Y5 Z0.2 F6000", "G1 X10 E0.5", "M400", "M155 S1"]
        for i, c in enumerate(cmds, 1):
            ser.write(framed(i, c))
            _readlines_until(ser, lambda s, i=i: s.startswith(f"ok N{i}"), limit=30)
        report = _readlines_until(ser, lambda s: s.startswith(" T:"), limit=10)[-1]
        assert "/0.00" in report
        fw = ser.simulator.firmware
        assert [t for n, t in fw.executed if n] == cmds
        assert fw.now >= fw.config.firmware.homing_time  # the clock is the wall clock
