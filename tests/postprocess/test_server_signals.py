"""SIGTERM to ``printability serve`` while it runs a request (issue #24): the run's own stop
handler (:func:`printability.app.cli.common.stop_signals_raise`) must not swallow it. The server
stops as when idle (socket removed, the client told to run it itself, its ticket gone) and
the file is left as it was."""

from __future__ import annotations

import os
import signal
import socket
import threading
import time

import pytest

import printability.postprocess
from printability.app.server import serve, stop_server
from printability.app.server_client import run_remote

pytestmark = pytest.mark.skipif(not hasattr(socket, "AF_UNIX"), reason="no Unix-domain sockets")

HANG = 60.0


def test_sigterm_during_a_served_run_stops_the_server(tmp_path, prusa_short, monkeypatch):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are set from the main thread only")
    private = tmp_path / "srv"
    private.mkdir(mode=0o700)
    address = str(private / "s.sock")
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    entered = threading.Event()

    def slow_postprocess(*_args, **_kw):  # the run, inside the CLI's stop_signals_raise block
        entered.set()
        deadline = time.monotonic() + HANG
        while time.monotonic() < deadline:
            time.sleep(0.05)
        raise AssertionError("SIGTERM never reached the run")

    monkeypatch.setattr(printability.postprocess, "postprocess_file", slow_postprocess)
    replies, events, listening = [], [], threading.Event()

    def on_event(msg: str) -> None:
        events.append(msg)
        if msg.startswith("listening"):
            listening.set()

    def client() -> None:
        assert listening.wait(HANG)
        replies.append(run_remote(["postprocess", "--nozzle", "ellipse:major=0.8,minor=0.3",
                                   str(path)], cwd=str(tmp_path),
                                  environ={"SLIC3R_NOZZLE_DIAMETER": "0.4"}, address=address))

    def killer() -> None:
        if entered.wait(HANG):
            os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10.0)
        if os.path.exists(address):  # the server kept serving: end it so the test reports
            stop_server(address)

    handler_before = signal.getsignal(signal.SIGTERM)
    threads = [threading.Thread(target=client, daemon=True),
               threading.Thread(target=killer, daemon=True)]
    for t in threads:
        t.start()
    result = serve(address=address, warm=False, on_event=on_event)
    threads[0].join(HANG)
    assert not threads[0].is_alive()
    assert entered.is_set(), events
    assert result.reason == "terminated", events
    assert replies == [None]  # the server stopped: the plug-in runs it here
    assert not os.path.exists(address)
    assert [p.name for p in private.iterdir()] == []  # no socket, no ticket
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    assert path.read_bytes() == prusa_short.read_bytes()
    assert signal.getsignal(signal.SIGTERM) is handler_before
