"""Deadlines between the plug-in and ``printability serve``: a silent or slow client holds up
nobody, a stopped or silent server holds up no export, and whichever side gives up, the file
is written once, with the bytes a local run writes (the ticket, see
:mod:`printability.app.server_client`)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_server_fuzz import RealServer

import printability.app.cli.main as cli_main
from plugin.prusaslicer import main as plugin_main
from printability.app import server_client
from printability.app.server import serve, server_status, stop_server
from printability.app.server_client import (
    PROTOCOL,
    read_message,
    reply_deadline,
    run_remote,
    send_message,
)
from printability.postprocess import already_processed

pytestmark = pytest.mark.skipif(not hasattr(socket, "AF_UNIX"), reason="no Unix-domain sockets")

ELLIPSE = "ellipse:major=0.8,minor=0.3"
PLUGIN = str(Path(sys.executable).with_name("printability-postprocess"))
HANG = 60.0  # s: far beyond any deadline under test; reaching it means something hung


@pytest.fixture()
def private(tmp_path):
    d = tmp_path / "srv"
    d.mkdir(mode=0o700)
    return d


class Server:
    """A server in a thread of this process, its log lines in :attr:`events`."""

    def __init__(self, address: Path, **kw):
        self.address = str(address)
        self.events: list[str] = []
        self.result = None
        ready = threading.Event()

        def event(msg):
            self.events.append(msg)
            if msg.startswith("listening"):
                ready.set()

        def run():
            try:
                self.result = serve(address=self.address, warm=False, on_event=event, **kw)
            finally:
                ready.set()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert ready.wait(30)

    def wait_for(self, text: str) -> str:
        deadline = time.monotonic() + HANG
        while True:
            for e in list(self.events):
                if text in e:
                    return e
            assert time.monotonic() < deadline, self.events
            time.sleep(0.02)

    def stop(self):
        if self.thread.is_alive():
            stop_server(self.address)
        self.thread.join(30)
        assert not self.thread.is_alive()
        return self.result


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _local_bytes(prusa_short: Path, tmp_path: Path, monkeypatch) -> bytes:
    """What the plug-in writes without a server."""
    path = _copy(prusa_short, tmp_path / "local.gcode")
    with monkeypatch.context() as m:
        m.setenv("PRINTABILITY_SERVER", "off")
        m.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
        assert plugin_main(["--nozzle", ELLIPSE, str(path)]) == 0
    return path.read_bytes()


def _run(path: Path, address: str, **kw):
    return run_remote(["postprocess", "--nozzle", ELLIPSE, str(path)], cwd=str(path.parent),
                      environ={"SLIC3R_NOZZLE_DIAMETER": "0.4"}, address=address, **kw)


def _left_behind(private: Path, tmp_path: Path) -> list[str]:
    """Tickets and temporary files nobody removed."""
    tickets = [p.name for p in private.iterdir() if p.name.startswith("ticket-")]
    temps = [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    return tickets + temps


# --- clients that do not talk --------------------------------------------------------------

def test_a_silent_client_holds_up_no_one(private, prusa_short, tmp_path):
    s = Server(private / "s.sock", request_timeout=2.0)
    request = {"protocol": PROTOCOL, "version": server_client.__version__, "op": "status"}
    body = json.dumps(request).encode()
    silent = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    trickler = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        silent.connect(s.address)
        trickler.connect(s.address)
        stop_trickling = threading.Event()
        sent = []

        def trickle():  # a whole request, one byte every 0.1 s: 5 s and more
            for b in len(body).to_bytes(4, "big") + body:
                if stop_trickling.wait(0.1):
                    return
                try:
                    trickler.sendall(bytes([b]))
                except OSError:
                    return
                sent.append(b)

        t = threading.Thread(target=trickle, daemon=True)
        t.start()
        # meanwhile another client is answered, and a run is served
        t0 = time.monotonic()
        assert server_status(s.address)["pid"] == os.getpid()
        path = _copy(prusa_short, tmp_path / "part.gcode")
        res = _run(path, s.address)
        assert res is not None and res.rc == 0, res
        assert time.monotonic() - t0 < HANG
        assert already_processed(path.read_bytes())
        # the silent and the trickling client are told off once their 2 s are up
        for conn in (silent, trickler):
            reply = read_message(conn, limit=1 << 20, deadline=time.monotonic() + HANG)
            assert reply == {"ok": False, "reason": "no whole request within 2 s"}
        stop_trickling.set()
        t.join(10)
        assert 0 < len(sent) < 4 + len(body)  # it was cut off mid-request
    finally:
        silent.close()
        trickler.close()
    assert s.stop().requests == 1
    assert sum("refused a request: no whole request within 2 s" in e for e in s.events) == 2


def test_too_many_connections_are_refused_at_once(private):
    from printability.app.server_connections import MAX_CLIENTS as _MAX_CLIENTS

    s = Server(private / "s.sock", request_timeout=3.0)
    idle = []
    try:
        for _ in range(_MAX_CLIENTS):
            c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            c.connect(s.address)
            idle.append(c)
        time.sleep(0.5)  # all accepted
        reply = _status_reply(s.address)
        assert reply == {"ok": False, "reason": f"busy: {_MAX_CLIENTS} connections open"}
        for c in idle:  # dropped after their 3 s
            assert read_message(c, limit=1 << 20, deadline=time.monotonic() + HANG)["ok"] is False
    finally:
        for c in idle:
            c.close()
    deadline = time.monotonic() + HANG
    while server_status(s.address) is None:  # and the server answers again
        assert time.monotonic() < deadline
        time.sleep(0.1)
    s.stop()


def _status_reply(address: str) -> dict | None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
        c.settimeout(HANG)
        c.connect(address)
        try:
            send_message(c, {"protocol": PROTOCOL, "version": server_client.__version__,
                             "op": "status"})
        except (BrokenPipeError, ConnectionResetError):
            pass  # a busy server writes its refusal and closes, maybe before the request
        return read_message(c, limit=1 << 20, deadline=time.monotonic() + HANG)


# --- servers that do not answer ------------------------------------------------------------

def test_the_reply_deadline_grows_with_the_input():
    assert reply_deadline({}) == 60.0
    assert reply_deadline({"a.gcode": [1, 2, 10 * 2**20, 4]}) == 60.0 + 200.0


def test_a_stale_socket_is_said_and_run_here(private, prusa_short, tmp_path):
    stale = private / "s.sock"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(stale))
    s.close()
    notes = []
    path = _copy(prusa_short, tmp_path / "part.gcode")
    assert _run(path, str(stale), note=notes.append) is None
    assert notes == [f"no server answers at {stale} (a stale socket)"]
    assert _left_behind(private, tmp_path) == []


def test_a_listener_that_never_answers_is_left(private, prusa_short, tmp_path, monkeypatch):
    # a server that never accepts (or accepts and never replies) is left after the silence
    monkeypatch.setattr(server_client, "_SILENCE", 1.0)
    address = str(private / "s.sock")
    mute = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    mute.bind(address)
    mute.listen(4)
    try:
        notes = []
        path = _copy(prusa_short, tmp_path / "part.gcode")
        t0 = time.monotonic()
        assert _run(path, address, note=notes.append) is None
        assert time.monotonic() - t0 < HANG
        assert notes == [f"the server at {address} fell silent for 1 s (stopped?)"]
        assert path.read_bytes() == prusa_short.read_bytes()
        assert _left_behind(private, tmp_path) == []
    finally:
        mute.close()


def _stopped_server_case(server: RealServer, prusa_short, tmp_path, monkeypatch, capsys):
    """SIGSTOP the server, export, check the fallback's output; SIGCONT and check that the
    server wrote nothing. Returns the export's stderr."""
    private = Path(server.address).parent
    expected = _local_bytes(prusa_short, tmp_path, monkeypatch)
    warm = _copy(prusa_short, tmp_path / "warm.gcode")  # the server's kernels loaded first
    assert (res := _run(warm, server.address)) is not None and res.rc == 0, res
    path = _copy(prusa_short, tmp_path / "part.gcode")
    os.kill(server.proc.pid, signal.SIGSTOP)
    try:
        capsys.readouterr()
        monkeypatch.setenv("PRINTABILITY_SERVER", server.address)
        monkeypatch.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
        t0 = time.monotonic()
        assert plugin_main(["--nozzle", ELLIPSE, str(path)]) == 0
        took = time.monotonic() - t0
        err = capsys.readouterr().err
        assert took < HANG, took
        assert path.read_bytes() == expected
        before = path.stat()
    finally:
        os.kill(server.proc.pid, signal.SIGCONT)
    # the server reads the request that waited in its socket, finds the ticket gone (or the
    # file changed) and writes nothing
    deadline = time.monotonic() + HANG
    while "declined postprocess" not in server.text():
        assert time.monotonic() < deadline, (server.text(), err, took)
        time.sleep(0.05)
    after = path.stat()
    assert (after.st_ino, after.st_mtime_ns, after.st_size) == \
        (before.st_ino, before.st_mtime_ns, before.st_size)
    assert path.read_bytes() == expected
    assert _left_behind(private, tmp_path) == []
    assert server.proc.poll() is None
    again = _copy(prusa_short, tmp_path / "again.gcode")
    assert (res := _run(again, server.address)) is not None and res.rc == 0, res
    assert again.read_bytes() == expected
    return err


def test_a_stopped_server_is_left_and_writes_nothing_later(tmp_path, prusa_short,
                                                           monkeypatch, capsys):
    monkeypatch.setattr(server_client, "_SILENCE", 2.0)
    server = RealServer(tmp_path / "srv")
    try:
        err = _stopped_server_case(server, prusa_short, tmp_path, monkeypatch, capsys)
    finally:
        server.close()
    assert err.splitlines()[0] == (f"printability: the server at {server.address} fell "
                                   "silent for 2 s (stopped?); running here instead")


@pytest.mark.slow
def test_a_stopped_server_and_the_real_plugin(tmp_path, prusa_short, monkeypatch):
    """The same with the plug-in as a slicer starts it, at its real deadlines."""
    server = RealServer(tmp_path / "srv")
    private = tmp_path / "srv"
    try:
        expected = _local_bytes(prusa_short, tmp_path, monkeypatch)
        path = _copy(prusa_short, tmp_path / "part.gcode")
        os.kill(server.proc.pid, signal.SIGSTOP)
        try:
            env = {**os.environ, "PRINTABILITY_SERVER": server.address,
                   "SLIC3R_NOZZLE_DIAMETER": "0.4"}
            t0 = time.monotonic()
            r = subprocess.run([PLUGIN, "--nozzle", ELLIPSE, str(path)], env=env,
                               capture_output=True, text=True, timeout=300)
            took = time.monotonic() - t0
        finally:
            os.kill(server.proc.pid, signal.SIGCONT)
        assert r.returncode == 0, r.stderr
        assert took < server_client._SILENCE + HANG
        assert r.stderr.splitlines()[0].endswith("(stopped?); running here instead")
        assert path.read_bytes() == expected
        before = path.stat()
        deadline = time.monotonic() + HANG
        while "declined postprocess" not in server.text():
            assert time.monotonic() < deadline, server.text()
            time.sleep(0.05)
        assert path.stat().st_mtime_ns == before.st_mtime_ns
        assert path.read_bytes() == expected
        assert _left_behind(private, tmp_path) == []
    finally:
        server.close()


# --- who writes: the ticket ----------------------------------------------------------------

def test_a_client_that_gave_up_first_gets_nothing_written(private, prusa_short, tmp_path,
                                                          monkeypatch):
    """The client's deadline passes while the server works; it takes the ticket; the server's
    write is refused, and the file is the client's to write."""
    monkeypatch.setattr(server_client, "_REPLY_BASE", 0.5)
    monkeypatch.setattr(server_client, "_REPLY_PER_MIB", 0.0)
    took = threading.Event()
    real_take, real_run = server_client.take_ticket, cli_main.run

    def take(path):
        got = real_take(path)
        took.set()
        return got

    def late_run(argv):  # the server runs only once the client gave up
        assert took.wait(HANG)
        return real_run(argv)

    monkeypatch.setattr(server_client, "take_ticket", take)
    monkeypatch.setattr(cli_main, "run", late_run)
    s = Server(private / "s.sock")
    try:
        path = _copy(prusa_short, tmp_path / "part.gcode")
        notes = []
        assert _run(path, s.address, note=notes.append) is None
        assert notes == [f"the server at {s.address} did not reply within 0.5 s"]
        line = s.wait_for("request 1:")
        assert line.endswith("-> exit 1; nothing written: the client had stopped waiting"), line
        assert path.read_bytes() == prusa_short.read_bytes()  # the server wrote nothing
        assert _left_behind(private, tmp_path) == []
    finally:
        monkeypatch.setattr(cli_main, "run", real_run)
        s.stop()
    # the plug-in then runs it here, once
    monkeypatch.setenv("PRINTABILITY_SERVER", "off")
    monkeypatch.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
    assert plugin_main(["--nozzle", ELLIPSE, str(path)]) == 0
    assert path.read_bytes() == _local_bytes(prusa_short, tmp_path, monkeypatch)


def test_a_server_that_took_the_ticket_first_is_waited_for(private, prusa_short, tmp_path,
                                                           monkeypatch):
    """The client's deadline passes after the server began writing: the client finds the
    ticket gone, waits for the reply and takes the served result (written once)."""
    monkeypatch.setattr(server_client, "_REPLY_BASE", 0.5)
    monkeypatch.setattr(server_client, "_REPLY_PER_MIB", 0.0)
    wrote = threading.Event()
    real_take, real_run = server_client.take_ticket, cli_main.run

    def take(path):  # the client's attempt comes after the server's write
        assert wrote.wait(HANG)
        return real_take(path)

    def run_then_dawdle(argv):
        rc = real_run(argv)
        wrote.set()
        time.sleep(1.0)  # past the client's deadline, within its grace
        return rc

    monkeypatch.setattr(server_client, "take_ticket", take)
    monkeypatch.setattr(cli_main, "run", run_then_dawdle)
    s = Server(private / "s.sock")
    try:
        path = _copy(prusa_short, tmp_path / "part.gcode")
        notes = []
        res = _run(path, s.address, note=notes.append)
        assert res is not None and res.rc == 0, (res, s.events)
        assert notes == []
        assert s.wait_for("request 1:").endswith("-> exit 0")
    finally:
        monkeypatch.setattr(cli_main, "run", real_run)
        monkeypatch.setattr(server_client, "take_ticket", real_take)
        s.stop()
    expected = _local_bytes(prusa_short, tmp_path, monkeypatch)
    assert path.read_bytes() == expected
    assert _left_behind(private, tmp_path) == []


@pytest.mark.slow
def test_a_server_stopped_mid_run_writes_nothing_when_continued(tmp_path, shared_data,
                                                                monkeypatch):
    """SIGSTOP while the server works on a larger file: the client leaves after the silence
    and the file is processed here; SIGCONT: the server finishes its run but its write is
    refused, and the file stays as the local run left it."""
    monkeypatch.setattr(server_client, "_SILENCE", 2.0)
    source = shared_data / "gcode" / "orcaslicer_2.3.0b2_klipper_arcs.gcode"  # ~5 s of work
    server = RealServer(tmp_path / "srv")
    try:
        warm = _copy(source, tmp_path / "warm.gcode")
        assert (res := _run(warm, server.address)) is not None and res.rc == 0, res
        path = _copy(source, tmp_path / "part.gcode")
        done, notes = [], []
        t = threading.Thread(target=lambda: done.append(_run(path, server.address,
                                                              note=notes.append)))
        t.start()
        time.sleep(1.0)
        os.kill(server.proc.pid, signal.SIGSTOP)
        try:
            t.join(HANG)
            assert not t.is_alive()
            if done[0] is not None:
                pytest.skip("the served run ended before the server could be stopped")
            assert notes == [f"the server at {server.address} fell silent for 2 s (stopped?)"]
            assert path.read_bytes() == source.read_bytes()  # nothing written yet
            monkeypatch.setenv("PRINTABILITY_SERVER", "off")
            monkeypatch.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
            assert plugin_main(["--nozzle", ELLIPSE, str(path)]) == 0  # the fallback
            local = path.read_bytes()
            before = path.stat()
        finally:
            os.kill(server.proc.pid, signal.SIGCONT)
        deadline = time.monotonic() + HANG
        while "nothing written: the client had stopped waiting" not in server.text():
            assert time.monotonic() < deadline, server.text()
            time.sleep(0.1)
        assert path.stat().st_mtime_ns == before.st_mtime_ns and path.read_bytes() == local
        assert already_processed(local) and local == warm.read_bytes()
        assert _left_behind(tmp_path / "srv", tmp_path) == []
    finally:
        server.close()
