"""``printability serve`` and the plug-in's hand-over to it (printability.app.server*)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from plugin.prusaslicer import main as plugin_main
from printability import __version__
from printability.app.server import serve, server_status, source_stamp, stop_server
from printability.app.server_client import (
    ServerAddressError,
    call,
    default_address,
    file_identities,
    forwarded_env,
    run_remote,
    secure_dir,
    server_policy,
)
from printability.errors import PrintabilityOSError
from printability.postprocess import already_processed

ELLIPSE = "ellipse:major=0.8,minor=0.3"
PLUGIN = str(Path(sys.executable).with_name("printability-postprocess"))
CLI = str(Path(sys.executable).with_name("printability"))

pytestmark = pytest.mark.skipif(not hasattr(socket, "AF_UNIX"), reason="no Unix-domain sockets")


@pytest.fixture()
def private(tmp_path):
    d = tmp_path / "srv"
    d.mkdir(mode=0o700)
    return d


class Server:
    """A server in a thread of this process (its kernels are this worker's, already compiled
    or compiled once for all the tests)."""

    def __init__(self, address: Path, **kw):
        self.address = str(address)
        self.result = None
        ready = threading.Event()

        def run():
            def event(msg):
                if msg.startswith("listening"):
                    ready.set()
            try:
                self.result = serve(address=self.address, warm=False, on_event=event, **kw)
            finally:
                ready.set()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert ready.wait(30)

    def stop(self):
        if self.thread.is_alive():
            stop_server(self.address)
        self.thread.join(30)
        assert not self.thread.is_alive()
        return self.result


@pytest.fixture()
def server(private):
    s = Server(private / "s.sock")
    yield s
    s.stop()


def _plugin(args, *, address, cwd, env_extra=None):
    env = {**os.environ, "PRINTABILITY_SERVER": address, "SLIC3R_NOZZLE_DIAMETER": "0.4",
           **(env_extra or {})}
    return subprocess.run([PLUGIN, *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


def test_served_run_writes_what_a_local_run_writes(server, prusa_short, tmp_path):
    remote, local = tmp_path / "remote.gcode", tmp_path / "local.gcode"
    remote.write_bytes(prusa_short.read_bytes())
    local.write_bytes(prusa_short.read_bytes())
    # the real entry point, as a slicer starts it; a relative path resolves in the caller's cwd
    r = _plugin(["--nozzle", ELLIPSE, "remote.gcode"], address=server.address, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    served = server.stop()
    assert served.requests == 1 and served.reason == "asked to stop"
    loc = _plugin(["--nozzle", ELLIPSE, "local.gcode"], address="off", cwd=tmp_path)
    assert loc.returncode == 0, loc.stderr
    assert remote.read_bytes() == local.read_bytes()
    assert already_processed(remote.read_bytes())
    assert r.stdout.replace("remote.gcode", "X").split(";")[:3] == \
        loc.stdout.replace("local.gcode", "X").split(";")[:3]


def test_served_error_is_the_same_paragraph_and_leaves_the_file(server, prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    r = _plugin(["--nozzle", "ellipse:major=0.8", str(path)], address=server.address,
                cwd=tmp_path)
    loc = _plugin(["--nozzle", "ellipse:major=0.8", str(path)], address="off", cwd=tmp_path)
    assert r.returncode == loc.returncode == 1
    assert r.stderr == loc.stderr and r.stderr.startswith("printability: error:")
    assert path.read_bytes() == prusa_short.read_bytes()


def test_request_environment_is_used_and_then_restored(server, prusa_short, tmp_path,
                                                       monkeypatch):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    monkeypatch.delenv("SLIC3R_NOZZLE_DIAMETER", raising=False)
    cwd = os.getcwd()
    # no --nozzle: the default nozzle is the slicer's SLIC3R_NOZZLE_DIAMETER, from the request
    res = run_remote(["postprocess", str(path)], cwd=str(tmp_path),
                     environ={"SLIC3R_NOZZLE_DIAMETER": "0.6"}, address=server.address)
    assert res is not None and res.rc == 0, res
    assert b"; printability: nozzle = circle:d=0.6\n" in path.read_bytes()
    # the request's variable and directory were the run's only
    assert "SLIC3R_NOZZLE_DIAMETER" not in os.environ
    assert os.getcwd() == cwd


def test_changed_source_makes_the_server_decline_and_stop(private, prusa_short, tmp_path):
    watched = tmp_path / "pkg"
    watched.mkdir()
    (watched / "mod.py").write_text("x = 1\n")
    s = Server(private / "s.sock", watch=[watched])
    (watched / "mod.py").write_text("x = 22\n")
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    assert run_remote(["postprocess", str(path)], cwd=str(tmp_path), environ={},
                      address=s.address) is None
    assert path.read_bytes() == prusa_short.read_bytes()  # declined before running
    res = s.stop()
    assert res.reason == "the installed source changed" and res.requests == 0
    assert not os.path.exists(s.address)


def test_source_stamp_sees_every_source_file_and_no_cache(tmp_path):
    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "__pycache__").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("a = 1\n")
    (tmp_path / "pkg" / "sub" / "b.py").write_text("b = 1\n")
    (tmp_path / "pkg" / "data.txt").write_text("not source\n")
    stamp = source_stamp([tmp_path / "pkg"])
    assert [Path(p).relative_to(tmp_path).as_posix() for p, _, _ in stamp] == [
        "pkg/a.py", "pkg/sub/b.py"]
    # compiled caches and data come and go with every run: they change nothing
    (tmp_path / "pkg" / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"x")
    (tmp_path / "pkg" / "__pycache__" / "k.nbi").write_bytes(b"x")
    (tmp_path / "pkg" / "data.txt").write_text("other\n")
    assert source_stamp([tmp_path / "pkg"]) == stamp
    # an edit in a subpackage, or a new module, does
    (tmp_path / "pkg" / "sub" / "b.py").write_text("b = 22\n")
    edited = source_stamp([tmp_path / "pkg"])
    assert edited != stamp
    (tmp_path / "pkg" / "sub" / "c.py").write_text("c = 1\n")
    assert len(source_stamp([tmp_path / "pkg"])) == 3


def test_other_version_is_declined(server):
    reply = call(server.address, {"op": "status", "version": "0.0.0-other"}, timeout=5)
    assert reply == {"ok": False, "reason": f"this server is printability {__version__} "
                                           f"(protocol 2)"}
    assert server_status(server.address)["pid"] == os.getpid()


def test_broken_server_falls_back_to_a_local_run(private, prusa_short, tmp_path, monkeypatch):
    address = str(private / "s.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(address)
    listener.listen(1)

    def accept_and_hang_up():
        conn, _ = listener.accept()
        conn.recv(10)
        conn.close()

    t = threading.Thread(target=accept_and_hang_up, daemon=True)
    t.start()
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    monkeypatch.setenv("PRINTABILITY_SERVER", address)
    monkeypatch.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
    assert plugin_main(["--nozzle", ELLIPSE, str(path)]) == 0
    t.join(10)
    listener.close()
    assert already_processed(path.read_bytes())


def test_no_server_means_no_remote_run(private, tmp_path):
    assert run_remote(["--version"], cwd=str(tmp_path), environ={},
                      address=str(private / "none.sock")) is None
    # a socket file nobody listens on (a killed server's) is no server either
    stale = private / "stale.sock"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(stale))
    s.close()
    assert run_remote(["--version"], cwd=str(tmp_path), environ={}, address=str(stale)) is None
    # ... and a new server takes its place
    srv = Server(stale)
    assert server_status(str(stale)) is not None
    srv.stop()


def test_one_server_per_address(server):
    with pytest.raises(PrintabilityOSError, match="already running"):
        serve(address=server.address, warm=False)


def test_directory_open_to_others_is_refused(tmp_path):
    open_dir = tmp_path / "open"
    open_dir.mkdir()
    open_dir.chmod(0o755)
    with pytest.raises(ServerAddressError, match="mode 0700"):
        secure_dir(str(open_dir), create=False)
    with pytest.raises(PrintabilityOSError, match="private directory"):
        serve(address=str(open_dir / "s.sock"), warm=False)
    assert call(str(open_dir / "s.sock"), {"op": "status"}, timeout=1) is None


def test_idle_server_stops(private):
    res = serve(address=str(private / "s.sock"), warm=False, idle_timeout=0.2)
    assert res.reason == "idle for 0.2 s" and res.requests == 0
    assert not (private / "s.sock").exists()


def test_address_and_forwarded_environment(tmp_path):
    assert default_address({"PRINTABILITY_SERVER": "off"}) is None
    assert default_address({"PRINTABILITY_SERVER": "/x/s.sock"}) == "/x/s.sock"
    runtime = tmp_path / "run"
    runtime.mkdir()
    assert default_address({"XDG_RUNTIME_DIR": str(runtime)}) == \
        str(runtime / "printability" / f"serve-{__version__}.sock")
    env = {"SLIC3R_LAYER_HEIGHT": "0.2", "PRINTABILITY_POSTPROCESS_ARGS": "-q", "HOME": "/h",
           "PRINTABILITY_SERVER": "/x"}
    assert forwarded_env(env) == {"SLIC3R_LAYER_HEIGHT": "0.2",
                                  "PRINTABILITY_POSTPROCESS_ARGS": "-q"}


def test_cli_status_and_stop_without_server(private):
    for flag in ("--status", "--stop"):
        r = subprocess.run([CLI, "serve", "--socket", str(private / "s.sock"), flag],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 1 and "no server at" in r.stdout


def test_cli_serves_and_stops(private):
    address = str(private / "s.sock")
    proc = subprocess.Popen([CLI, "serve", "--socket", address, "--no-warm"],
                            stderr=subprocess.PIPE, text=True)
    try:
        assert "listening on" in proc.stderr.readline()
        r = subprocess.run([CLI, "serve", "--socket", address, "--status"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and f"pid {proc.pid}" in r.stdout
        r = subprocess.run([CLI, "serve", "--socket", address, "--stop"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and "stopped" in r.stdout
        assert proc.wait(60) == 0
    finally:
        proc.kill()
    assert not os.path.exists(address)


def test_cli_server_stops_on_sigterm_and_removes_its_socket(private):
    address = str(private / "s.sock")
    proc = subprocess.Popen([CLI, "serve", "--socket", address, "--no-warm"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "listening on" in proc.stderr.readline()
        proc.terminate()
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "(terminated)" in out
    assert not os.path.exists(address)


def test_cli_postprocess_is_served_too(server, prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    env = {**os.environ, "PRINTABILITY_SERVER": server.address, "SLIC3R_NOZZLE_DIAMETER": "0.4"}
    r = subprocess.run([CLI, "postprocess", "--nozzle", ELLIPSE, str(path)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert server.stop().requests == 1
    assert already_processed(path.read_bytes())


def test_server_declines_files_it_does_not_see_as_the_caller_does(server, private,
                                                                  prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    files = file_identities(["postprocess", str(path), "--nozzle", ELLIPSE], str(tmp_path))
    assert list(files) == [str(path)]
    ticket = "ticket-" + "0" * 32
    (private / ticket).touch()
    base = {"op": "run", "argv": ["postprocess", str(path)], "cwd": str(tmp_path), "env": {},
            "ticket": ticket}
    # another inode under the same name (a sandbox's own /tmp, say): the caller runs it
    other = dict(files)
    other[str(path)] = [*files[str(path)][:1], files[str(path)][1] + 1, *files[str(path)][2:]]
    reply = call(server.address, {**base, "files": other}, timeout=60)
    assert reply["ok"] is False and "not the caller's file" in reply["reason"]
    # nor a directory it does not have
    reply = call(server.address, {**base, "cwd": str(tmp_path / "gone"), "files": {}},
                 timeout=60)
    assert reply["ok"] is False and "no such directory here" in reply["reason"]
    # only postprocess is served
    reply = call(server.address, {**base, "argv": ["analyze", str(path)], "files": files},
                 timeout=60)
    assert reply == {"ok": False, "reason": "this server only runs postprocess"}
    assert path.read_bytes() == prusa_short.read_bytes()
    assert server.stop().requests == 0


@pytest.mark.parametrize(("argv", "env", "expected"), [
    (["postprocess", "a.gcode"], {}, "use"),
    (["postprocess", "--server", "start", "a.gcode"], {}, "start"),
    (["postprocess", "--server=OFF", "a.gcode"], {}, "off"),
    (["postprocess", "--server", "start", "--server", "use", "a.gcode"], {}, "use"),
    (["postprocess", "--server", "start", "a.gcode"], {"PRINTABILITY_SERVER": "off"}, "off"),
    (["postprocess", "--server", "bogus", "a.gcode"], {}, "off"),  # the local run says why
    (["postprocess", "--", "--server", "start"], {}, "use"),
])
def test_server_policy(argv, env, expected):
    assert server_policy(argv, env) == expected


def test_server_off_is_never_served(server, prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    r = _plugin(["--server", "off", "--nozzle", ELLIPSE, str(path)], address=server.address,
                cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert server.stop().requests == 0
    assert already_processed(path.read_bytes())


def test_unknown_server_policy_is_a_clear_error(prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    r = _plugin(["--server", "bogus", str(path)], address="off", cwd=tmp_path)
    assert r.returncode == 1
    assert "unknown server policy 'bogus'; expected one of: use, start, off" in r.stderr
    assert path.read_bytes() == prusa_short.read_bytes()


def test_server_start_starts_one_for_the_next_exports(private, prusa_short, tmp_path):
    address = str(private / "s.sock")
    first, second = tmp_path / "first.gcode", tmp_path / "second.gcode"
    for p in (first, second):
        p.write_bytes(prusa_short.read_bytes())
    # a socket file nobody listens on, as a killed server leaves: no server either
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(address)
    stale.close()
    try:
        # no server yet: this run is done here, and one is started in the background
        r = _plugin(["--server", "start", "--nozzle", ELLIPSE, str(first)], address=address,
                    cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert already_processed(first.read_bytes())
        deadline = time.monotonic() + 120
        while server_status(address) is None:
            assert time.monotonic() < deadline, (private / "serve.log").read_text()
            time.sleep(0.2)
        r = _plugin(["--server", "start", "--nozzle", ELLIPSE, str(second)], address=address,
                    cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert second.read_bytes() == first.read_bytes()
    finally:
        stop_server(address)
    # the socket goes first, then the server logs its end
    deadline = time.monotonic() + 60
    while "(asked to stop) after 1 requests" not in (private / "serve.log").read_text():
        assert time.monotonic() < deadline, (private / "serve.log").read_text()
        time.sleep(0.2)
    assert not os.path.exists(address)
    log = (private / "serve.log").read_text()
    assert "request 1: postprocess --server start" in log and "idle-timeout" not in log


def test_a_server_that_does_not_answer_yet_is_not_replaced(private):
    # a server still warming up listens but accepts only later: its socket must stay
    address = str(private / "s.sock")
    busy = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    busy.bind(address)
    busy.listen(4)
    try:
        with pytest.raises(PrintabilityOSError, match="already running"):
            serve(address=address, warm=False)
        assert os.path.exists(address)
    finally:
        busy.close()


_FAULTS = """
import resource, sys
import numpy as np
from printability.app.server import retain_freed_memory
kept = retain_freed_memory() if sys.argv[1] == "keep" else False
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
def request():  # a request's arrays (the cube: about 48 MB): allocated, written, freed
    arrays = [np.ones(n) for n in (2_300_000, 1_700_000, 1_700_000)]
    del arrays
request()
f0 = faults()
for _ in range(5):
    request()
print(kept, faults() - f0)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_a_server_keeps_freed_memory_for_the_next_request():
    """By default glibc gives freed heap back to the system once more than twice the
    largest block is free, so every request faults part of its arrays back in (about
    2 000 pages a round here, 12 000 for the cube's post-processing); kept, the next
    rounds fault none."""
    runs = {}
    for mode in ("default", "keep"):
        out = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True,
                             text=True, check=True).stdout.split()
        runs[mode] = (out[0] == "True", int(out[1]))
    assert runs["keep"][0] is True
    assert runs["default"][1] > 5 * 1_000
    assert runs["keep"][1] < runs["default"][1] / 10


def test_the_client_starts_on_the_standard_library_alone():
    """Every export pays the client's start: it imports neither the libraries the work needs
    nor the heavy parts of the standard library (``dataclasses`` pulls in ``inspect``;
    ``typing`` alone is about 10 ms; ``socket`` 6 ms, for ``enum`` and ``selectors``)."""
    code = ("import sys; import plugin.prusaslicer, printability.app.server_client; "
            "print(' '.join(sorted(m for m in ('numpy', 'numba', 'shapely', 'typer', 'rich', "
            "'dataclasses', 'inspect', 'typing', 'socket', 'selectors', 'struct', 'shlex') "
            "if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == ""
