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

Conventions, written once here and shared with :mod:`printability.server`:

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
    (:func:`file_identities`), and only ``postprocess`` runs are served. The
    reply to a run is ``{"ok": true, "rc", "stdout",
    "stderr"}``, or ``{"ok": false, "reason"}`` when the server declines (see
    :mod:`printability.server` for when).
Policy
    ``postprocess --server use`` (the default) hands the run over when a
    server answers; ``--server start`` also starts one in the background when
    none is running (this run is done here), so the next exports are served;
    ``--server off`` (or ``PRINTABILITY_SERVER=off``) never hands over.
Falling back
    Whenever no reply comes (no server, a refused or broken connection, a
    decline, which includes a server that does not see the caller's files as
    the caller does), the caller runs the command itself. That is always safe: the
    server replaces files atomically, and a file it did finish is marked as
    processed, so running again leaves it as it is.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from collections import namedtuple
from collections.abc import Mapping

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
    "RemoteResult",
    "ServerAddressError",
    "call",
    "default_address",
    "file_identities",
    "forwarded",
    "forwarded_env",
    "recv_message",
    "run_remote",
    "run_served",
    "secure_dir",
    "send_message",
    "server_policy",
    "start_in_background",
]

PROTOCOL = 1
_MAX_MESSAGE = 64 * 2**20  # a reply carries a command's output: far below this
_CONNECT_TIMEOUT = 2.0  # s; a live server accepts at once (its backlog queues clients)


class ServerAddressError(PrintabilityOSError):
    """The server's socket directory is not the user's own private directory."""


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


def _recv_exactly(sock: _sock.socket, n: int) -> bytes | None:
    chunks, got = [], 0
    while got < n:
        chunk = sock.recv(min(n - got, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def recv_message(sock: _sock.socket) -> dict | None:
    """Receive one length-prefixed JSON object; ``None`` if the peer closed first or sent
    something that is not one."""
    head = _recv_exactly(sock, 4)
    if head is None:
        return None
    n = int.from_bytes(head, "big")
    if n > _MAX_MESSAGE:
        return None
    body = _recv_exactly(sock, n)
    if body is None:
        return None
    try:
        obj = json.loads(body.decode("utf-8"))
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None


def call(address: str, request: Mapping[str, object], *, timeout: float | None) -> dict | None:
    """One request to the server at ``address``; its reply, or ``None`` when there is no
    server there or it closed without replying. ``timeout`` bounds the wait for the reply
    (s; ``None``: as long as the work takes)."""
    if not os.path.exists(address):
        return None
    try:
        secure_dir(os.path.dirname(address) or ".", create=False)
    except ServerAddressError:
        return None
    sock = _sock.socket(_sock.AF_UNIX, _sock.SOCK_STREAM)
    try:
        sock.settimeout(_CONNECT_TIMEOUT)
        sock.connect(address)
        sock.settimeout(timeout)
        send_message(sock, {"protocol": PROTOCOL, "version": __version__, **request})
        return recv_message(sock)
    except OSError:  # refused (a stale socket file), reset, timed out: no server
        return None
    finally:
        sock.close()


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
            start_new_session=True, cwd=folder)
    except OSError:
        return False
    finally:
        log.close()
    return True


def run_remote(argv: list[str], *, cwd: str, environ: Mapping[str, str],
               address: str | None = None) -> RemoteResult | None:
    """Run the ``printability`` command ``argv`` on the server; ``None`` when the caller must
    run it itself (see the module docs: no server, or it declined or broke off).

    Parameters
    ----------
    argv
        The command's arguments (without the program name), as for
        :func:`printability.cli.main.main`.
    cwd
        The directory relative paths in ``argv`` are relative to.
    environ
        The caller's environment (only :func:`forwarded_env` of it is sent).
    address
        The socket (default: :func:`default_address` of ``environ``).
    """
    address = default_address(environ) if address is None else address
    policy = server_policy(argv, environ)
    if address is None or policy == "off":
        return None
    reply = call(address, {"op": "run", "argv": list(argv), "cwd": cwd,
                           "env": forwarded_env(environ), "files": file_identities(argv, cwd)},
                 timeout=None)
    if reply is None and policy == "start":  # nobody answered (a stale socket file included)
        start_in_background(address)
    if not reply or reply.get("ok") is not True:
        return None
    rc, out, err = reply.get("rc"), reply.get("stdout"), reply.get("stderr")
    if not (isinstance(rc, int) and isinstance(out, str) and isinstance(err, str)):
        return None
    return RemoteResult(rc, out, err)


def run_served(argv: list[str]) -> int | None:
    """:func:`run_remote` for this process (its directory and environment), printing what
    the served run printed; its exit code, or ``None`` when this process must run it."""
    result = run_remote(argv, cwd=os.getcwd(), environ=os.environ)
    if result is None:
        return None
    sys.stdout.write(result.stdout)
    sys.stdout.flush()
    sys.stderr.write(result.stderr)
    sys.stderr.flush()
    return result.rc
