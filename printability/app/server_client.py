"""The plug-in's side of ``printability serve``: hand a post-processing run to a warm server.

A slicer starts its post-processing script as a new process for every export.
Most of that process's time on a small part is the start of the libraries,
not the work: numba's import, set-up and cached-kernel loads alone are about
1 s, numpy, shapely and typer another 0.3 s (see the README's performance
table). ``printability serve`` pays that once and then runs each request in
its warm process; :func:`run_remote` is what the ``printability-postprocess``
entry point and ``printability postprocess`` (so also the Cura shim, which runs
it) call first. It uses the standard library only, so a client
costs Python's own start and a socket round trip.

Conventions, written once here and shared with :mod:`printability.app.server`:

Address
    A Unix-domain socket. ``PRINTABILITY_SERVER`` in the environment names
    it (a path), or is ``off`` to never use a server. By default it is
    ``$XDG_RUNTIME_DIR/printability/serve-<version>.sock``, or
    ``<temp dir>/printability-<uid>/serve-<version>.sock`` without
    ``XDG_RUNTIME_DIR``. The version is in the name, so an upgraded plug-in
    never talks to an older server. The directory must belong to the user and
    be closed to others (mode 0700): only the user can connect, and a
    directory that does not pass that check is not used. Platforms without
    Unix-domain sockets (Windows' Python) always run locally.
Messages
    One request and one reply per connection, each a JSON object preceded by
    its length (4 bytes, big-endian). A request carries ``protocol``,
    ``version`` and ``op``: ``run`` (with ``argv``, ``cwd`` and ``env``, the
    caller's ``SLIC3R_*`` and ``PRINTABILITY_*`` variables), ``status`` or
    ``stop``; a run also lists the identity of each file its arguments name
    (:func:`file_identities`) and names its *ticket* (below), and only
    ``postprocess`` runs are served. The reply to a run is ``{"ok": true, "rc",
    "stdout", "stderr"}``, or ``{"ok": false, "reason"}`` when the server
    declines (see :mod:`printability.app.server` for when) or refuses a malformed
    request. While a request waits for its turn or runs, the server sends an
    empty frame (length 0) every second: a server that falls silent (stopped,
    wedged) is told from a slow one.
Deadlines
    Connecting: :data:`_CONNECT_TIMEOUT`. The reply: :func:`reply_deadline`,
    a minute plus 20 s per MiB of input (real work takes from a fraction of a
    second to a minute), and no more than :data:`_SILENCE` without a byte
    from the server. The server, for its part, drops a client that has not
    sent its whole request within 10 s.
Ticket
    Before a run, the client creates an empty file ``ticket-<random>`` beside
    the socket and names it in the request. Whoever *removes* it first writes
    the output: the server removes it just before it replaces the first file
    (and declines a run whose ticket is already gone); a client that gives up
    waiting removes it before running the command itself. Removing a file
    succeeds once, so exactly one of them writes, and a server that resumes
    after the client gave up (a stopped server continued, a slow one
    finishing) writes nothing. A client that finds the ticket gone when it
    gives up (the server is writing) waits :data:`_GRACE` more for the reply.
    Only when the server falls silent right after taking the ticket does the
    client run the command too: it then reads the processed file (and leaves
    it as it is) or, if the server stopped in the instant between taking the
    ticket and ``os.replace``, the original, which it processes to the bytes
    the server would write.
Policy
    ``postprocess --server use`` (the default) hands the run over when a
    server answers; ``--server start`` also starts one in the background when
    none is running (this run is done here), so the next exports are served;
    ``--server off`` (or ``PRINTABILITY_SERVER=off``) never hands over.
Falling back
    Whenever no reply comes (no server, a stale socket, a refused, broken or
    timed-out connection, a silent server, a decline, which includes a server
    that does not see the caller's files as the caller does), the caller runs
    the command itself; :func:`run_served` says so in one line on stderr
    when a server was there but failed it (not when there is none, nor when
    it declines). That is always safe: the ticket keeps the server from writing
    once the caller gave up, the server replaces files atomically, and a file
    it did finish is marked as processed, so running again leaves it as it is.
"""

from __future__ import annotations

import json
import os
import stat
import sys
import time
from collections import namedtuple
from collections.abc import Callable, Mapping

from printability import __version__
from printability.errors import PrintabilityOSError
from printability.options import SERVER_POLICIES

try:
    # The C module the public ``socket`` wraps, with the same socket type and constants:
    # ``socket``'s own import (enum, selectors, array) is about 6 ms of every export's
    # start, and a client of one connection uses none of what it adds.
    import _socket as _sock
except ImportError:  # a Python without it: the public module has the same names
    import socket as _sock

__all__ = [
    "IDLE_TIMEOUT",
    "PROTOCOL",
    "TICKET_PREFIX",
    "MessageError",
    "RemoteResult",
    "ServerAddressError",
    "call",
    "default_address",
    "file_identities",
    "forwarded",
    "forwarded_env",
    "read_message",
    "recv_message",
    "reply_deadline",
    "run_remote",
    "run_served",
    "secure_dir",
    "send_message",
    "server_policy",
    "start_in_background",
    "take_ticket",
]

PROTOCOL = 2  # 2: heartbeat frames, tickets
_MAX_MESSAGE = 64 * 2**20  # a reply carries a command's output: far below this
_CONNECT_TIMEOUT = 2.0  # s; a live server accepts at once (its backlog queues clients)
_REPLY_BASE = 60.0  # s the reply to a run may take, plus ...
_REPLY_PER_MIB = 20.0  # ... this per MiB of the files it names (the work: ~0.1-1 s per MiB)
_SILENCE = 15.0  # s without a byte from the server (it sends one frame a second): stalled
_GRACE = 10.0  # s more for a server that took the ticket (it is writing) to reply
TICKET_PREFIX = "ticket-"  # + 32 hex digits, in the socket's directory


class ServerAddressError(PrintabilityOSError):
    """The server's socket directory is not the user's own private directory."""


class MessageError(ValueError):
    """Bytes that are not one message of the protocol; the text says what is wrong (one
    line)."""


class RemoteResult(namedtuple("RemoteResult", ["rc", "stdout", "stderr"])):
    """A run done by the server: its exit code ``rc`` (int) and what it printed, ``stdout``
    and ``stderr`` (str).

    (A ``collections`` named tuple, neither a dataclass nor ``typing.NamedTuple``:
    ``dataclasses`` imports ``inspect`` and ``typing`` costs about 10 ms, which every
    export would pay; ``collections`` is already imported by ``re``.)
    """

    __slots__ = ()


def secure_dir(path: str, *, create: bool) -> str:
    """Return ``path`` after checking that it is a directory owned by the user with no access
    for others (creating it with mode 0700 when ``create``); raise :class:`ServerAddressError`
    otherwise."""
    if create:
        os.makedirs(path, mode=0o700, exist_ok=True)
    try:
        st = os.lstat(path)
    except OSError as exc:
        raise ServerAddressError(f"{path}: {exc.strerror}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise ServerAddressError(f"{path}: expected a directory, found another kind of file")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise ServerAddressError(f"{path}: expected a directory of yours, found user "
                                 f"{st.st_uid}'s")
    if st.st_mode & 0o077:
        raise ServerAddressError(f"{path}: expected a private directory (mode 0700), found "
                                 f"mode {stat.S_IMODE(st.st_mode):o}")
    return path


def default_address(environ: Mapping[str, str] | None = None) -> str | None:
    """The server's socket path, or ``None`` when servers are off (``PRINTABILITY_SERVER=off``)
    or unsupported here."""
    env = os.environ if environ is None else environ
    chosen = env.get("PRINTABILITY_SERVER", "")
    if chosen.lower() == "off" or not hasattr(_sock, "AF_UNIX"):
        return None
    if chosen:
        return chosen
    runtime = env.get("XDG_RUNTIME_DIR", "")
    if runtime and os.path.isdir(runtime):
        base = os.path.join(runtime, "printability")
    else:
        import tempfile

        uid = os.getuid() if hasattr(os, "getuid") else 0
        base = os.path.join(tempfile.gettempdir(), f"printability-{uid}")
    return os.path.join(base, f"serve-{__version__}.sock")


def forwarded(key: str) -> bool:
    """Whether a run depends on the environment variable ``key``: the slicer's ``SLIC3R_*``
    and our ``PRINTABILITY_*``, the server address itself excepted."""
    return (key.startswith(("SLIC3R_", "PRINTABILITY_"))) and key != "PRINTABILITY_SERVER"


def forwarded_env(environ: Mapping[str, str]) -> dict[str, str]:
    """The variables of ``environ`` a run depends on (:func:`forwarded`)."""
    return {k: v for k, v in environ.items() if forwarded(k)}


def send_message(sock: _sock.socket, obj: Mapping[str, object]) -> None:
    """Send one length-prefixed JSON object."""
    data = json.dumps(obj).encode("utf-8")
    sock.sendall(len(data).to_bytes(4, "big") + data)


def decode_message(body: bytes) -> dict:
    """The JSON object ``body`` holds; :class:`MessageError` when it holds none (not UTF-8,
    not JSON, nested deeper than the parser's recursion limit, not an object)."""
    try:
        obj = json.loads(body.decode("utf-8"))
    except UnicodeDecodeError:
        raise MessageError("not UTF-8 text") from None
    except RecursionError:
        raise MessageError("JSON nested too deeply") from None
    except MemoryError:
        raise MessageError("JSON too large to hold") from None
    except ValueError as exc:  # json.JSONDecodeError, and an integer of too many digits
        raise MessageError(f"not JSON ({' '.join(str(exc).split())[:80]})") from None
    if not isinstance(obj, dict):
        raise MessageError(f"expected a JSON object, found a {type(obj).__name__}")
    return obj


def read_message(sock: _sock.socket, *, limit: int,
                 deadline: float | None = None) -> dict | None:
    """Receive one length-prefixed JSON object of at most ``limit`` bytes before the
    ``time.monotonic()`` instant ``deadline`` (``None``: the socket's own timeout per
    receive). ``None`` when the peer closed before sending a byte.

    Raises
    ------
    MessageError
        A frame that is empty, longer than ``limit``, cut short by the peer or not a JSON
        object.
    TimeoutError
        ``deadline`` passed (or the socket's timeout, between two receives) first.
    OSError
        The connection failed.
    """
    head = _recv_exactly(sock, 4, deadline, first=True)
    if head is None:
        return None
    n = int.from_bytes(head, "big")
    if n == 0:
        raise MessageError("an empty message")
    if n > limit:
        raise MessageError(f"a message of {n} bytes, more than the {limit} allowed")
    return decode_message(_recv_exactly(sock, n, deadline, first=False))


def _recv_exactly(sock: _sock.socket, n: int, deadline: float | None, *,
                  first: bool) -> bytes | None:
    chunks, got = [], 0
    while got < n:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("timed out")
            sock.settimeout(left)
        chunk = sock.recv(min(n - got, 1 << 20))
        if not chunk:
            if first and got == 0:
                return None
            what = "length" if first else "message"
            raise MessageError(f"the {what} ended after {got} of its {n} bytes")
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def recv_message(sock: _sock.socket) -> dict | None:
    """Receive one length-prefixed JSON object (the socket's timeout per receive); ``None`` if
    the peer closed first or sent something that is not one."""
    try:
        return read_message(sock, limit=_MAX_MESSAGE)
    except (MessageError, OSError):
        return None


class _GaveUp(Exception):
    """No reply: the one-line note says why (``None``: nothing worth saying)."""

    def __init__(self, note: str | None):
        super().__init__(note)
        self.note = note


def _await_reply(sock: _sock.socket, address: str, timeout: float | None,
                 give_up: Callable[[], bool] | None) -> dict:
    """The reply frame on ``sock``, heartbeats skipped; :class:`_GaveUp` when it does not come
    within ``timeout`` s (``None``: no limit), the server falls silent for :data:`_SILENCE`,
    or it breaks off. Past a deadline, ``give_up()`` decides: true, stop waiting; false (the
    server has begun writing), wait :data:`_GRACE` more."""
    buf = bytearray()
    graced = False
    end = None if timeout is None else time.monotonic() + timeout
    while True:
        while len(buf) >= 4:
            n = int.from_bytes(buf[:4], "big")
            if n == 0:  # a heartbeat
                del buf[:4]
                continue
            if n > _MAX_MESSAGE:
                raise _GaveUp(f"the server at {address} sent a reply of {n} bytes")
            if len(buf) < 4 + n:
                break
            try:
                return decode_message(bytes(buf[4:4 + n]))
            except MessageError as exc:
                raise _GaveUp(f"the server at {address} sent a malformed reply ({exc})") from None
        now = time.monotonic()
        wait = _SILENCE if end is None else min(_SILENCE, end - now)
        try:
            if wait <= 0:
                raise TimeoutError
            sock.settimeout(wait)
            chunk = sock.recv(1 << 20)
        except TimeoutError:
            late = end is not None and time.monotonic() >= end
            if graced:
                note = (f"the server at {address} began writing, then fell silent for "
                        f"{_GRACE:g} s")
            elif late:
                note = f"the server at {address} did not reply within {_secs(timeout)} s"
            else:
                note = f"the server at {address} fell silent for {_SILENCE:g} s (stopped?)"
            if graced or give_up is None or give_up():
                raise _GaveUp(note) from None
            graced, end = True, time.monotonic() + _GRACE  # it is writing: let it reply
            continue
        except OSError as exc:
            raise _GaveUp(f"the connection to the server at {address} failed "
                          f"({exc.strerror or exc})") from None
        if not chunk:
            raise _GaveUp(f"the server at {address} closed the connection without a reply")
        buf += chunk


def _secs(seconds: float) -> str:
    return f"{seconds:.0f}" if seconds >= 10 else f"{seconds:.2g}"


def _exchange(address: str, request: Mapping[str, object], *, timeout: float | None,
              give_up: Callable[[], bool] | None = None) -> dict:
    """Send ``request`` to the server at ``address`` and return its reply (see
    :func:`_await_reply` for ``timeout`` and ``give_up``); :class:`_GaveUp` otherwise."""
    if not os.path.exists(address):
        raise _GaveUp(None)  # no server: the usual case, nothing to say
    try:
        secure_dir(os.path.dirname(address) or ".", create=False)
    except ServerAddressError:
        raise _GaveUp(None) from None
    sock = _sock.socket(_sock.AF_UNIX, _sock.SOCK_STREAM)
    try:
        sock.settimeout(_CONNECT_TIMEOUT)
        try:
            sock.connect(address)
        except FileNotFoundError:  # removed meanwhile: the server stopped
            raise _GaveUp(None) from None
        except ConnectionRefusedError:
            raise _GaveUp(f"no server answers at {address} (a stale socket)") from None
        except (TimeoutError, BlockingIOError, InterruptedError):
            raise _GaveUp(f"the server at {address} did not take the connection within "
                          f"{_CONNECT_TIMEOUT:g} s") from None
        except OSError as exc:
            raise _GaveUp(f"cannot connect to the server at {address} "
                          f"({exc.strerror or exc})") from None
        try:
            sock.settimeout(_SILENCE)  # a request fits in the socket's buffer: at once
            send_message(sock, {"protocol": PROTOCOL, "version": __version__, **request})
        except TimeoutError:
            if give_up is not None:
                give_up()
            raise _GaveUp(f"the server at {address} did not read the request within "
                          f"{_SILENCE:g} s (stopped?)") from None
        except OSError as exc:
            raise _GaveUp(f"the connection to the server at {address} failed "
                          f"({exc.strerror or exc})") from None
        return _await_reply(sock, address, timeout, give_up)
    finally:
        sock.close()


def call(address: str, request: Mapping[str, object], *, timeout: float | None) -> dict | None:
    """One request to the server at ``address``; its reply, or ``None`` when there is no
    server there, or it closed, fell silent (:data:`_SILENCE`) or did not reply within
    ``timeout`` s (``None``: as long as the work takes)."""
    try:
        return _exchange(address, request, timeout=timeout)
    except _GaveUp:
        return None


def reply_deadline(files: Mapping[str, list[int]]) -> float:
    """Seconds the client waits for a run's reply: :data:`_REPLY_BASE` plus
    :data:`_REPLY_PER_MIB` per MiB of the files the command names (``files`` as
    :func:`file_identities` gives them)."""
    size = sum(ident[2] for ident in files.values())
    return _REPLY_BASE + _REPLY_PER_MIB * size / 2**20


def _new_ticket(folder: str) -> str | None:
    """Create an empty ticket file in ``folder`` (the socket's private directory); its name,
    or ``None`` when it cannot be created."""
    for _ in range(3):
        name = TICKET_PREFIX + os.urandom(16).hex()
        try:
            fd = os.open(os.path.join(folder, name), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            continue
        except OSError:
            return None
        os.close(fd)
        return name
    return None


def take_ticket(path: str) -> bool:
    """Remove the ticket at ``path``; whether this call removed it (the other side had not:
    the caller now decides who writes, see the module docs)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        return False
    except OSError:  # not ours to decide: as if the server had it
        return False
    return True


def _identity(path: str) -> list[int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns]


def file_identities(argv: list[str], cwd: str) -> dict[str, list[int]]:
    """(device, inode, size, mtime ns) of every argument naming a regular file (relative to
    ``cwd``): the server runs only if it sees the same files (a sandbox or container with
    its own /tmp would not), otherwise the caller does."""
    out = {}
    for arg in argv:
        if arg.startswith("-") or arg in out:
            continue
        ident = _identity(os.path.join(cwd, arg))
        if ident is not None:
            out[arg] = ident
    return out


def server_policy(argv: list[str], environ: Mapping[str, str]) -> str:
    """The ``--server`` choice of a ``postprocess`` command line (the last one given; see
    :data:`printability.options.SERVER_POLICIES`), ``off`` when ``PRINTABILITY_SERVER`` is
    ``off``. An unknown value counts as ``off``: the local run then reports it."""
    if environ.get("PRINTABILITY_SERVER", "").lower() == "off":
        return "off"
    choice = "use"
    for i, arg in enumerate(argv):
        if arg == "--":
            break
        if arg == "--server" and i + 1 < len(argv):
            choice = argv[i + 1]
        elif arg.startswith("--server="):
            choice = arg.split("=", 1)[1]
    choice = choice.strip().lower()
    return choice if choice in SERVER_POLICIES.choices else "off"


IDLE_TIMEOUT = 900.0
"""Seconds without a request after which a server started by ``--server start`` stops."""


def start_in_background(address: str) -> bool:
    """Start ``printability serve`` at ``address`` as a detached process (its own session,
    output to ``serve.log`` beside the socket, stopping after :data:`IDLE_TIMEOUT` idle
    seconds); whether it was started. Its kernels load on its first request (the caller's
    run, just done here, has them compiled and cached)."""
    import subprocess

    try:
        folder = secure_dir(os.path.dirname(address) or ".", create=True)
        log = open(os.path.join(folder, "serve.log"), "ab")
    except OSError:
        return False
    try:
        subprocess.Popen(
            [sys.executable, "-m", "printability", "serve", "--socket", address,
             "--idle-timeout", f"{IDLE_TIMEOUT:g}", "--no-warm"],
            stdin=subprocess.DEVNULL, stdout=log, stderr=log, close_fds=True,
            start_new_session=True, cwd=folder,
            env={**os.environ, "PYTHONSAFEPATH": "1"})  # `-m` would import from cwd first
    except OSError:
        return False
    finally:
        log.close()
    return True


def run_remote(argv: list[str], *, cwd: str, environ: Mapping[str, str],
               address: str | None = None,
               note: Callable[[str], None] | None = None) -> RemoteResult | None:
    """Run the ``printability`` command ``argv`` on the server; ``None`` when the caller must
    run it itself (see the module docs: no server, or it declined, broke off or missed a
    deadline).

    Parameters
    ----------
    argv
        The command's arguments (without the program name), as for
        :func:`printability.app.cli.main.main`.
    cwd
        The directory relative paths in ``argv`` are relative to.
    environ
        The caller's environment (only :func:`forwarded_env` of it is sent).
    address
        The socket (default: :func:`default_address` of ``environ``).
    note
        Called with one line (no newline) when a server was there but failed the run: a
        stale socket, a broken connection, a missed deadline, a silent server.
    """
    address = default_address(environ) if address is None else address
    policy = server_policy(argv, environ)
    if address is None or policy == "off":
        return None
    files = file_identities(argv, cwd)
    folder = os.path.dirname(address) or "."
    ticket = None
    if os.path.exists(address):
        try:
            ticket = _new_ticket(secure_dir(folder, create=False))
        except ServerAddressError:
            pass
    if ticket is None:  # no server, or a folder not ours alone or not writable: none to use
        reply = None
    else:
        path = os.path.join(folder, ticket)
        try:
            reply = _exchange(address, {"op": "run", "argv": list(argv), "cwd": cwd,
                                        "env": forwarded_env(environ), "files": files,
                                        "ticket": ticket},
                              timeout=reply_deadline(files),
                              give_up=lambda: take_ticket(path))
        except _GaveUp as exc:
            reply = None
            if exc.note and note is not None:
                note(exc.note)
        finally:
            take_ticket(path)  # left when the server wrote nothing (or never got the request)
    if reply is None and policy == "start":  # nobody answered (a stale socket file included)
        start_in_background(address)
    if not reply or reply.get("ok") is not True:
        return None
    rc, out, err = reply.get("rc"), reply.get("stdout"), reply.get("stderr")
    if not (isinstance(rc, int) and isinstance(out, str) and isinstance(err, str)):
        return None
    return RemoteResult(rc, out, err)


def _note(line: str) -> None:
    sys.stderr.write(f"printability: {line}; running here instead\n")
    sys.stderr.flush()


def run_served(argv: list[str]) -> int | None:
    """:func:`run_remote` for this process (its directory and environment), printing what
    the served run printed; its exit code, or ``None`` when this process must run it (said
    in one line on stderr when a server was there but failed it)."""
    result = run_remote(argv, cwd=os.getcwd(), environ=os.environ, note=_note)
    if result is None:
        return None
    sys.stdout.write(result.stdout)
    sys.stdout.flush()
    sys.stderr.write(result.stderr)
    sys.stderr.flush()
    return result.rc
