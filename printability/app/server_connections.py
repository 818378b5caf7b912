"""The connection side of ``printability serve``: reading, checking and queueing requests.

Each connection has its own thread (:class:`Clients`), which reads the request
within the server's request timeout and :data:`MAX_REQUEST` bytes and checks
every field (:func:`check_request`); anything else is answered with a one-line
refusal (:class:`Refusal`), and logged. Status requests are answered there;
run and stop requests are queued as :class:`Job` s for the serving thread
(:func:`printability.app.server.serve`), and while one waits or runs its thread
sends the client a heartbeat a second.
"""

from __future__ import annotations

import contextlib
import os
import queue
import re
import select
import socket
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

from printability import __version__
from printability.app.server_client import (
    PROTOCOL,
    TICKET_PREFIX,
    MessageError,
    forwarded,
    read_message,
    send_message,
)

__all__ = ["MAX_CLIENTS", "MAX_REQUEST", "STOPPING", "TICKET_NAME", "Clients", "Job", "Refusal",
           "check_request", "printable"]

MAX_REQUEST = 8 << 20  # bytes; a slicer's whole environment is below 2 MiB (ARG_MAX)
MAX_CLIENTS = 32  # connections served at once; more are refused at once
_MAX_ITEMS = 10_000  # arguments, variables or files in a request
_HEARTBEAT = 1.0  # s between the empty frames sent to a client waiting for its reply
_SEND_TIMEOUT = 10.0  # s for a reply (or a heartbeat) to leave; a client that does not read

# --- what a request may hold ------------------------------------------------------------

class Refusal(Exception):
    """A request not served; the text is the one-line reason sent back and logged."""


_FIELDS = {
    "status": frozenset({"protocol", "version", "op"}),
    "stop": frozenset({"protocol", "version", "op"}),
    "run": frozenset({"protocol", "version", "op", "argv", "cwd", "env", "files", "ticket"}),
}
TICKET_NAME = re.compile(TICKET_PREFIX + r"[0-9a-f]{32}\Z")


def _show(value: object) -> str:
    """A value for a one-line message: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _kind(value: object) -> str:
    names = {str: "a string", bool: "true or false", int: "a number", float: "a number",
             list: "a list", dict: "an object", type(None): "null"}
    return names.get(type(value), type(value).__name__)


def _text(value: object, what: str) -> str:
    """``value`` when it is a string a file name, an argument or a variable can hold."""
    if not isinstance(value, str):
        raise Refusal(f"malformed request: {what} must be a string, not {_kind(value)}")
    if "\0" in value:
        raise Refusal(f"malformed request: {what} {_show(value)} contains a NUL character")
    try:
        os.fsencode(value)
    except UnicodeError:
        raise Refusal(f"malformed request: {what} {_show(value)} cannot be encoded for the "
                       "system") from None
    return value


def _collection(value: object, kind: type, what: str) -> None:
    if not isinstance(value, kind):
        raise Refusal(f"malformed request: {what} must be {_kind(kind())}, not {_kind(value)}")
    if len(value) > _MAX_ITEMS:
        raise Refusal(f"malformed request: {what} has {len(value)} items, more than "
                       f"{_MAX_ITEMS}")


def check_request(req: dict) -> str:
    """The operation of a request (``run``, ``status`` or ``stop``) after checking each of
    its fields; :class:`Refusal` (an exception whose text is the reply's one-line reason)
    otherwise.

    A run's ``argv`` is a list of strings starting with ``postprocess``, ``cwd`` an absolute
    path, ``env`` an object of ``SLIC3R_*``/``PRINTABILITY_*`` variables (strings, with no
    ``=`` or NUL in a name and no NUL in a value), ``files`` an object mapping arguments to
    four integers, ``ticket`` a ticket's name; strings hold no NUL and can be encoded as file
    names. No other field is accepted.
    """
    protocol, version = req.get("protocol"), req.get("version")
    if type(protocol) is not int or protocol != PROTOCOL or version != __version__:
        raise Refusal(f"this server is printability {__version__} (protocol {PROTOCOL})")
    op = req.get("op")
    if not isinstance(op, str) or op not in _FIELDS:
        raise Refusal(f"malformed request: expected a run, status or stop request, not op "
                       f"{_show(op)}")
    extra = sorted(set(req) - _FIELDS[op])
    if extra:
        raise Refusal(f"malformed request: unexpected field {_show(extra[0])} in a {op} "
                       "request")
    if op != "run":
        return op
    missing = sorted(_FIELDS[op] - set(req))
    if missing:
        raise Refusal(f"malformed request: a run needs the field {_show(missing[0])}")
    argv = req["argv"]
    _collection(argv, list, "argv")
    for i, arg in enumerate(argv):
        _text(arg, f"argv[{i}]")
    cwd = _text(req["cwd"], "cwd")
    if not os.path.isabs(cwd):
        raise Refusal(f"malformed request: cwd {_show(cwd)} is not an absolute path")
    env = req["env"]
    _collection(env, dict, "env")
    for key, value in env.items():
        if not key or "=" in key or "\0" in key or not forwarded(key):
            raise Refusal(f"malformed request: env name {_show(key)} is not a SLIC3R_ or "
                           "PRINTABILITY_ variable name (no '=' nor NUL)")
        _text(key, "env name")
        _text(value, f"env[{_show(key)}]")
    files = req["files"]
    _collection(files, dict, "files")
    for arg, ident in files.items():
        if arg not in argv:
            raise Refusal(f"malformed request: files names {_show(arg)}, not an argument")
        if not (isinstance(ident, list) and len(ident) == 4
                and all(type(n) is int and n >= 0 for n in ident)):
            raise Refusal(f"malformed request: files[{_show(arg)}] must be four integers "
                           "(device, inode, size, time)")
    ticket = req["ticket"]
    if not isinstance(ticket, str) or not TICKET_NAME.match(ticket):
        raise Refusal(f"malformed request: ticket {_show(ticket)} is not a ticket's name")
    if argv[:1] != ["postprocess"]:
        raise Refusal("this server only runs postprocess")
    return op


# --- connections ------------------------------------------------------------------------

@dataclass(eq=False)
class Job:
    """A request handed from its connection's thread to the serving thread."""

    op: str
    req: dict
    ticket: str = ""
    done: threading.Event = field(default_factory=threading.Event)
    reply: dict | None = None
    left: bool = False  # the client hung up while waiting
    wrote: bool = False  # the run took the ticket (its files are written)
    refused: bool = False  # the run's write was refused: the client had taken the ticket

    def finish(self, reply: dict) -> None:
        if not self.done.is_set():
            self.reply = reply
            self.done.set()


STOPPING = {"ok": False, "reason": "the server is stopping"}


def printable(argv: list[str]) -> str:
    """A command line for the log, on one line whatever its arguments hold."""
    return " ".join(a if a.isprintable() else repr(a) for a in argv)


class Clients:
    """The listening socket's thread and one thread per connection: they read and check
    requests, answer status requests and refusals, and queue the rest (:attr:`jobs`, with
    the log lines they write, which the serving thread prints: during a run its standard
    streams are the run's)."""

    def __init__(self, sock: socket.socket, ticket_dir: str, request_timeout: float):
        self.sock = sock
        self.ticket_dir = ticket_dir
        self.request_timeout = request_timeout
        self.jobs: queue.SimpleQueue = queue.SimpleQueue()
        self.lock = threading.Lock()
        self.stopping = False
        self.active = 0
        self.last_seen = time.monotonic()
        self.thread = threading.Thread(target=self._accept_loop, name="printability-accept",
                                       daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        """Stop taking connections; queued requests are declined by the caller."""
        with self.lock:
            self.stopping = True
        if self.thread.is_alive():
            self.thread.join(5.0)

    def log(self, msg: str) -> None:
        self.jobs.put(msg)

    def idle_for(self) -> float | None:
        """Seconds since the last connection ended, or ``None`` while one is open."""
        with self.lock:
            return None if self.active else time.monotonic() - self.last_seen

    def _accept_loop(self) -> None:
        self.sock.settimeout(0.5)  # to see `stopping`
        while not self.stopping:
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self.stopping:
                    return
                self.log(f"cannot accept a connection: {exc.strerror or exc}")
                time.sleep(0.1)  # out of file descriptors, say: let some close
                continue
            with self.lock:
                self.last_seen = time.monotonic()
                busy = self.active >= MAX_CLIENTS
                if not busy:
                    self.active += 1
            if busy:
                self._refuse(conn, f"busy: {MAX_CLIENTS} connections open")
                conn.close()
                continue
            try:
                threading.Thread(target=self._client, args=(conn,), daemon=True).start()
            except RuntimeError:  # no thread to be had
                self._done()
                self._refuse(conn, "busy: cannot start a thread")
                conn.close()

    def _done(self) -> None:
        with self.lock:
            self.active -= 1
            self.last_seen = time.monotonic()

    def _client(self, conn: socket.socket) -> None:
        try:
            with conn:
                self._converse(conn)
        except Exception:  # a bug: keep serving the others
            self.log("error while serving a client:\n" + traceback.format_exc().rstrip())
        finally:
            self._done()

    def _converse(self, conn: socket.socket) -> None:
        deadline = time.monotonic() + self.request_timeout
        try:
            req = read_message(conn, limit=MAX_REQUEST, deadline=deadline)
        except MessageError as exc:
            self._refuse(conn, f"malformed request: {exc}")
            return
        except TimeoutError:
            self._refuse(conn, f"no whole request within {self.request_timeout:g} s")
            return
        except OSError:  # the connection broke: nobody to answer
            return
        if req is None:  # connected and closed (a probe)
            return
        try:
            op = check_request(req)
        except Refusal as exc:
            self._refuse(conn, str(exc))
            return
        if op == "status":
            self._reply(conn, {"ok": True, "pid": os.getpid(), "version": __version__,
                               "python": sys.executable})
            return
        job = Job(op, req, os.path.join(self.ticket_dir, req["ticket"]) if op == "run" else "")
        with self.lock:
            queued = not self.stopping
            if queued:
                self.jobs.put(job)
        if not queued:
            self._reply(conn, STOPPING)
            return
        if self._wait(conn, job):
            self._reply(conn, job.reply)

    def _wait(self, conn: socket.socket, job: Job) -> bool:
        """Wait for ``job``, sending a heartbeat a second; false when the client left."""
        while not job.done.wait(_HEARTBEAT):
            try:
                if _hung_up(conn):
                    job.left = True
                    return False
                conn.settimeout(_SEND_TIMEOUT)
                conn.sendall(b"\0\0\0\0")
            except OSError:
                job.left = True
                return False
        return True

    def _reply(self, conn: socket.socket, reply: dict | None) -> None:
        if reply is None:
            return
        with contextlib.suppress(OSError):  # the client gave up: nothing to tell it
            conn.settimeout(_SEND_TIMEOUT)
            send_message(conn, reply)

    def _refuse(self, conn: socket.socket, reason: str) -> None:
        self.log(f"refused a request: {reason}")
        with contextlib.suppress(OSError):
            conn.settimeout(1.0)
            send_message(conn, {"ok": False, "reason": reason})


def _hung_up(conn: socket.socket) -> bool:
    """Whether the client closed its end (or sent more than its request: not a client of
    this protocol). It sends nothing after its request, so anything readable says so."""
    poller = select.poll()
    poller.register(conn, select.POLLIN)
    return bool(poller.poll(0))
