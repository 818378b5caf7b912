"""Malformed requests against a real ``printability serve`` process: every one is answered with
a one-line refusal, the server stays up, and a well-formed request is served afterwards."""

from __future__ import annotations

import json
import os
import random
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from printability import __version__
from printability.app.server import check_request, server_status
from printability.app.server_client import PROTOCOL, read_message, run_remote
from printability.app.server_connections import Refusal as _Refusal
from printability.postprocess import already_processed

pytestmark = pytest.mark.skipif(not hasattr(socket, "AF_UNIX"), reason="no Unix-domain sockets")

CLI = str(Path(sys.executable).with_name("printability"))
LIMIT = 8 << 20  # the server's request limit (printability.app.server._MAX_REQUEST)
TICKET = "ticket-" + "ab" * 16
DEFAULT_CASES = 400
SLOW_CASES = 4000


def _valid(tmp: Path) -> dict:
    """A well-formed run request (declined when sent: its ticket does not exist)."""
    return {"protocol": PROTOCOL, "version": __version__, "op": "run",
            "argv": ["postprocess", "--nozzle", "circle:d=0.4", "part.gcode"],
            "cwd": str(tmp), "env": {"SLIC3R_NOZZLE_DIAMETER": "0.4"},
            "files": {"part.gcode": [1, 2, 3, 4]}, "ticket": TICKET}


def _frame(obj) -> bytes:
    body = obj if isinstance(obj, bytes) else json.dumps(obj).encode()
    return len(body).to_bytes(4, "big") + body


_WRONG = [None, True, 0, -1, 1.5, "", "x", [], [1], {}, {"a": 1}, ["postprocess", 1]]


def _malformed(rng: random.Random, tmp: Path) -> tuple[str, bytes]:
    """One malformed request (a family name, the bytes to send)."""
    base = _valid(tmp)
    family = rng.choice(["deep", "huge", "type", "env", "cut", "random", "mutate", "fields"])
    if family == "deep":
        depth = rng.choice([1_000, 5_000, 100_000])
        opener, closer = rng.choice([("[", "]"), ('{"a":', "}")])
        inner = opener * depth + "1" + closer * depth
        if rng.random() < 0.5:
            return family, _frame(inner.encode())
        return family, _frame(json.dumps(base)[:-1].encode() + b', "deep": ' + inner.encode()
                              + b"}")
    if family == "huge":
        n = rng.choice([LIMIT + 1, 2**31, 2**32 - 1, rng.randrange(LIMIT + 1, 2**32)])
        return family, n.to_bytes(4, "big") + os.urandom(rng.randrange(0, 4096))
    if family == "type":
        key = rng.choice(["protocol", "version", "op", "argv", "cwd", "env", "files", "ticket"])
        base[key] = rng.choice([w for w in _WRONG if type(w) is not type(base[key])])
        return family, _frame(base)
    if family == "env":
        key, value = rng.choice([
            ("SLIC3R_A=B", "1"), ("=SLIC3R_A", "1"), ("SLIC3R_A\0", "1"), ("", "1"),
            ("HOME", "/tmp"), ("PATH", "/bin"), ("SLIC3R_A", "x\0y"), ("SLIC3R_A", 1),
            ("SLIC3R_A", None), ("SLIC3R_A", ["1"]), ("SLIC3R_A", "\ud800"),
            ("PRINTABILITY_\udcff\ud800", "1")])
        base["env"] = {key: value}
        return family, _frame(json.dumps(base).encode())
    if family == "cut":
        data = _frame(base)
        return family, data[:rng.randrange(1, len(data))]
    if family == "random":
        body = os.urandom(rng.randrange(0, 2048))
        if rng.random() < 0.5:  # a length that matches: the body itself is wrong
            return family, len(body).to_bytes(4, "big") + body
        return family, body + b"\0"  # whatever length its first bytes say (never 0 bytes)
    if family == "mutate":  # byte flips of a request the server declines in several ways
        base.update(argv=["analyze", "part.gcode"], cwd="/nonexistent/dir")
        data = bytearray(json.dumps(base).encode())
        for _ in range(rng.randrange(1, 8)):
            pos = rng.randrange(len(data))
            if rng.random() < 0.2:
                data[pos] = rng.randrange(256)
            elif rng.random() < 0.5:
                data[pos:pos + 1] = b""
            else:
                data[pos] = rng.choice(b'{}[]",:\\ 0123456789-.eEtrufalsn\x00\x7f')
        return family, _frame(bytes(data))
    # fields: missing, unknown, NUL, relative paths, bad argv / files / ticket
    change = rng.choice([
        lambda r: r.pop(rng.choice(["argv", "cwd", "env", "files", "ticket"])),
        lambda r: r.update(extra=1),
        lambda r: r.update(cwd="relative/dir"),
        lambda r: r.update(cwd="/tmp/\0x"),
        lambda r: r.update(argv=["postprocess", "a\0b"]),
        lambda r: r.update(argv=[]),
        lambda r: r.update(argv=["postprocess"] * 20_000),
        lambda r: r.update(files={"other.gcode": [1, 2, 3, 4]}),
        lambda r: r.update(files={"part.gcode": [1, 2, 3]}),
        lambda r: r.update(files={"part.gcode": [1, 2, 3, -4]}),
        lambda r: r.update(files={"part.gcode": [1, 2, 3, True]}),
        lambda r: r.update(ticket="../../etc/passwd"),
        lambda r: r.update(ticket="ticket-" + "g" * 32),
        lambda r: r.update(op="stop", argv=None),
        lambda r: r.update(op="status", extra=True),
        lambda r: r.update(op="STOP"),
        lambda r: r.update(protocol=True),
        lambda r: r.update(protocol=float(PROTOCOL)),
    ])
    change(base)
    return family, _frame(json.dumps(base).encode())


def _send(address: str, data: bytes) -> dict | None:
    """Send ``data``, close the writing side and read the reply (``None``: no reply)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(30)
        s.connect(address)
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)
        except OSError:  # the server refused before reading all of it
            pass
        try:
            return read_message(s, limit=1 << 20, deadline=time.monotonic() + 30)
        except ConnectionResetError:  # closed with our bytes unread, and no reply queued
            return None


class RealServer:
    """``printability serve`` in its own process, its output in ``log``."""

    def __init__(self, folder: Path):
        folder.mkdir(mode=0o700, exist_ok=True)
        self.address = str(folder / "s.sock")
        self.log = folder / "serve.log"
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen([CLI, "serve", "--socket", self.address, "--no-warm"],
                                         stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while "listening on" not in self.text():
            assert self.proc.poll() is None, self.text()
            assert time.monotonic() < deadline, self.text()
            time.sleep(0.05)

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()


@pytest.fixture(scope="module")
def real_server(tmp_path_factory):
    s = RealServer(tmp_path_factory.mktemp("fuzz") / "srv")
    yield s
    s.close()


def _fuzz(real_server, tmp_path, cases: int, seed: int) -> None:
    rng = random.Random(seed)
    seen: dict[str, int] = {}
    for i in range(cases):
        family, data = _malformed(rng, tmp_path)
        seen[family] = seen.get(family, 0) + 1
        reply = _send(real_server.address, data)
        assert reply is not None, (i, family, data[:200], real_server.text()[-2000:])
        assert reply.get("ok") is False, (i, family, data[:200], reply)
        reason = reply.get("reason")
        assert isinstance(reason, str) and reason and "\n" not in reason, (family, reply)
        assert real_server.proc.poll() is None, real_server.text()[-2000:]
    assert len(seen) == 8, seen
    log = real_server.text()
    assert "Traceback" not in log and "error while" not in log, log[-3000:]
    assert log.count("refused a request: ") >= cases - seen["mutate"]


def _still_serves(real_server, prusa_short, tmp_path) -> None:
    status = server_status(real_server.address)
    assert status is not None and status["pid"] == real_server.proc.pid
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    res = run_remote(["postprocess", "--nozzle", "ellipse:major=0.8,minor=0.3", str(path)],
                     cwd=str(tmp_path), environ={"SLIC3R_NOZZLE_DIAMETER": "0.4"},
                     address=real_server.address)
    assert res is not None and res.rc == 0, (res, real_server.text()[-2000:])
    assert already_processed(path.read_bytes())


def test_the_requests_that_used_to_end_the_server(real_server, prusa_short, tmp_path):
    base = _valid(tmp_path)
    cases = {
        "nested 100 000 deep": _frame(b"[" * 100_000 + b"]" * 100_000),
        "an '=' in a variable's name": _frame({**base, "env": {"SLIC3R_A=B": "1"}}),
        "a NUL in a variable's value": _frame({**base, "env": {"SLIC3R_A": "1\0"}}),
        "a NUL in the directory": _frame({**base, "cwd": str(tmp_path) + "\0"}),
        "a number too long for int()": _frame(b'{"protocol": ' + b"9" * 100_000 + b"}"),
    }
    for name, data in cases.items():
        reply = _send(real_server.address, data)
        assert reply is not None and reply["ok"] is False, (name, reply)
        assert real_server.proc.poll() is None, (name, real_server.text())
    _still_serves(real_server, prusa_short, tmp_path)


def test_an_oversized_request_is_refused_unread(real_server):
    reply = _send(real_server.address, _frame(b" " * (LIMIT + 1)))
    assert reply == {"ok": False, "reason": f"malformed request: a message of {LIMIT + 1} "
                                            f"bytes, more than the {LIMIT} allowed"}


def test_malformed_requests_are_refused_and_the_server_stays_up(real_server, prusa_short,
                                                                tmp_path):
    _fuzz(real_server, tmp_path, DEFAULT_CASES, seed=30)
    _still_serves(real_server, prusa_short, tmp_path)


@pytest.mark.slow
def test_many_malformed_requests(real_server, prusa_short, tmp_path):
    _fuzz(real_server, tmp_path, SLOW_CASES, seed=3030)
    _still_serves(real_server, prusa_short, tmp_path)


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(),
                     lambda inner: st.lists(inner, max_size=4)
                     | st.dictionaries(st.text(), inner, max_size=4), max_leaves=12)


@settings(max_examples=300)
@given(field=st.sampled_from(["protocol", "version", "op", "argv", "cwd", "env", "files",
                              "ticket", "extra"]),
       value=_json)
def test_any_field_value_is_checked_or_refused(field, value):
    """Whatever JSON a field holds, the check accepts the request or refuses it with one line;
    it raises nothing else."""
    req = _valid(Path("/tmp"))
    req[field] = value
    try:
        assert check_request(req) == "run"
    except _Refusal as exc:
        assert str(exc) and "\n" not in str(exc)


_names = st.sampled_from(["SLIC3R_", "PRINTABILITY_"]).flatmap(
    lambda prefix: st.text(max_size=8).map(lambda rest: prefix + rest))


@settings(max_examples=300)
@given(env=st.dictionaries(_names, st.text(max_size=8), max_size=4),
       argv=st.lists(st.text(max_size=8), max_size=4))
def test_accepted_variables_and_arguments_are_usable(env, argv):
    """A request the check accepts can be put in the environment and on a command line."""
    req = {**_valid(Path("/tmp")), "env": env, "argv": ["postprocess", *argv], "files": {}}
    try:
        check_request(req)
    except _Refusal as exc:
        bad_env = any("=" in k or "\0" in k + v or not _encodable(k + v)
                      or k == "PRINTABILITY_SERVER" for k, v in env.items())
        bad_argv = any("\0" in a or not _encodable(a) for a in argv)
        assert bad_env or bad_argv, exc
        return
    for key, value in env.items():
        os.environ[key] = value
        assert os.environ.pop(key) == value
    for arg in argv:
        os.fsencode(arg)


def _encodable(text: str) -> bool:
    try:
        os.fsencode(text)
    except UnicodeError:
        return False
    return True
