"""``printability serve``: a warm process that runs the slicer plug-in's post-processing.

The ``printability-postprocess`` entry point first offers its run to this
server (:func:`printability.server_client.run_remote`, where the address,
the messages and the fall-back rule are documented) and runs locally only
when there is none. The server runs each request as the command line would
(:func:`printability.cli.main.run`), in its own process, one at a time in
the order they arrive, with the request's working directory and its
``SLIC3R_*``/``PRINTABILITY_*`` variables, and returns the exit code and
what the command printed. The output file is therefore byte for byte what a
local run writes, and an error is the same one paragraph with exit code 1.

It declines (and the client runs locally) when the client's version is not
its own, when a file the command names is not the one the client sees (same
device, inode, size and time: a sandbox or container with its own /tmp), and
for any command but ``postprocess``; it declines and stops when any source file of the installed
packages changed since it started (an edited or upgraded install), so it
never runs code other than what is on disk.

Complexity: per request the work itself, plus a stat of the packages' source
files (about a millisecond) and a JSON round trip of the command's output.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import signal
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from printability import __version__
from printability.errors import PrintabilityOSError
from printability.server_client import (
    PROTOCOL,
    ServerAddressError,
    call,
    default_address,
    file_identities,
    forwarded,
    recv_message,
    secure_dir,
    send_message,
)

__all__ = ["ServeResult", "retain_freed_memory", "serve", "server_status", "source_stamp",
           "stop_server"]

_PACKAGES = ("printability", "gcode", "machine_io", "plugin", "simulators")
_REQUEST_TIMEOUT = 10.0  # s to receive a request once connected (a silent client is dropped)
_KEEP_BELOW = 64 << 20  # bytes: blocks up to this come from the heap and are reused
_KEEP_FREE = 256 << 20  # bytes of freed heap kept for the next request


def retain_freed_memory() -> bool:
    """Ask the C library's allocator to keep freed memory for the next request (glibc).

    A request allocates and frees tens of MB of arrays (the cube: about 48 MB).
    By default glibc maps every block over 128 kB afresh and returns freed
    heap to the system, so each request page-faults its memory back in: 12 000
    faults, 0.03–0.05 s of system time in a 0.5 s request. With blocks up to
    ``_KEEP_BELOW`` taken from the heap and up to ``_KEEP_FREE`` of free heap
    kept, a server's requests fault almost nothing once a few have run. The
    memory kept is bounded by those two sizes and the largest request.
    Process-wide, hence only for a process that is the server
    (``printability serve``). Returns whether the allocator took the settings
    (False on other C libraries and platforms, where nothing changes).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    return mallopt(m_mmap_threshold, _KEEP_BELOW) == 1 and mallopt(m_trim_threshold,
                                                                   _KEEP_FREE) == 1


@dataclass(frozen=True)
class ServeResult:
    """How a server ended: requests run, why it stopped, its lifetime (s)."""

    requests: int
    reason: str
    seconds: float


def _package_roots() -> list[Path]:
    import importlib.util

    roots = []
    for name in _PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            roots.extend(Path(p) for p in spec.submodule_search_locations)
    return roots


def source_stamp(roots: Iterable[Path]) -> tuple[tuple[str, int, int], ...]:
    """(path, mtime ns, size) of every ``.py`` file under ``roots``, sorted: what the server
    compares before every request to decide that the install changed under it. O(files).

    ``os.scandir`` rather than ``Path.rglob``, and ``__pycache__`` (hundreds of numba cache
    files, no source) is not listed: 1 ms instead of 5 per request.
    """
    out = []
    stack = [str(root) for root in roots]
    while stack:
        try:
            entries = os.scandir(stack.pop())
        except OSError:
            continue
        with entries:
            for e in entries:
                if e.name == "__pycache__":
                    continue
                try:
                    if e.is_dir(follow_symlinks=False):
                        stack.append(e.path)
                    elif e.name.endswith(".py"):
                        st = e.stat()
                        out.append((e.path, st.st_mtime_ns, st.st_size))
                except OSError:  # gone meanwhile
                    continue
    return tuple(sorted(out))


def _run_command(argv: list[str], cwd: str, env: dict[str, str]) -> tuple[int, str, str]:
    """Run the CLI in this process as a new process would, with the request's directory and
    variables; restore both afterwards."""
    from printability.cli.main import run as cli_run  # not main: it would ask this server

    saved_cwd = os.getcwd()
    saved = {k: v for k, v in os.environ.items() if forwarded(k)}
    out, err = io.StringIO(), io.StringIO()
    try:
        for k in saved:
            del os.environ[k]
        os.environ.update({k: v for k, v in env.items() if forwarded(k)})
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = cli_run(list(argv))
            except Exception:  # a bug: report it as the CLI would and keep serving
                traceback.print_exc()
                rc = 1
    except OSError as exc:  # the request's directory is gone
        return 1, "", f"printability: error: {cwd}: {exc.strerror}\n"
    finally:
        os.chdir(saved_cwd)
        for k in [k for k in os.environ if forwarded(k) and k not in saved]:
            del os.environ[k]
        os.environ.update(saved)
    return rc, out.getvalue(), err.getvalue()


def _valid_run(req: dict) -> bool:
    return (isinstance(req.get("argv"), list) and all(isinstance(a, str) for a in req["argv"])
            and isinstance(req.get("cwd"), str) and isinstance(req.get("env"), dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in req["env"].items())
            and isinstance(req.get("files"), dict)
            and all(isinstance(k, str) and isinstance(v, list) for k, v in req["files"].items()))


def _listening(address: str) -> bool:
    """Whether a process listens at ``address`` (a connection is accepted into its backlog
    even while it is busy)."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(5.0)
        probe.connect(address)
        return True
    except OSError:
        return False
    finally:
        probe.close()


def _bind(address: str) -> socket.socket:
    try:
        secure_dir(os.path.dirname(address) or ".", create=True)
    except ServerAddressError as exc:
        raise PrintabilityOSError(f"server socket {address}: {exc}") from None
    except OSError as exc:
        raise PrintabilityOSError(f"server socket {address}: cannot create its directory: "
                                  f"{exc.strerror}") from None
    if os.path.exists(address):
        if _listening(address):  # (a server still warming up accepts only later)
            raise PrintabilityOSError(
                f"server socket {address}: a server is already running there; stop it with "
                f"`printability serve --stop` first")
        os.unlink(address)  # a stale socket file left by a server that was killed
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(address)
        os.chmod(address, 0o600)
        sock.listen(16)
    except OSError as exc:
        sock.close()
        raise PrintabilityOSError(f"server socket {address}: cannot listen there: "
                                  f"{exc.strerror}") from None
    return sock


def serve(
    *,
    address: str | None = None,
    idle_timeout: float | None = None,
    warm: bool = True,
    watch: Iterable[Path] | None = None,
    on_event: Callable[[str], None] | None = None,
    retain_memory: bool = False,
) -> ServeResult:
    """Serve post-processing requests until stopped, idle or stale.

    Parameters
    ----------
    address
        The socket path (default: :func:`printability.server_client.default_address`).
    idle_timeout
        Stop after this many seconds without a request (``None``: never).
    warm
        Load the plug-in's compiled kernels before the first request
        (:func:`printability.warmup.warm_up`: seconds when cached, about a
        minute right after an install).
    watch
        Directories whose ``.py`` files are compared before each run (default:
        the installed packages'); any change stops the server.
    on_event
        Called with a one-line message on start, per request and on stop.
    retain_memory
        Keep freed memory for the next request (:func:`retain_freed_memory`):
        process-wide, so for a process that only serves.

    Raises
    ------
    PrintabilityOSError
        No address on this platform, a directory that is not private, or a
        server already running at ``address``.
    """
    t0 = time.perf_counter()
    address = default_address() if address is None else address
    if address is None:
        raise PrintabilityOSError(
            "printability serve: no server address: PRINTABILITY_SERVER is 'off', or this "
            "Python has no Unix-domain sockets (Windows); the plug-in then runs on its own")
    say = on_event or (lambda _msg: None)
    roots = list(watch) if watch is not None else _package_roots()
    stamp = source_stamp(roots)
    sock = _bind(address)
    requests, reason = 0, "stopped"

    terminated = []

    def _terminate(signum, _frame):
        # the CLI turns KeyboardInterrupt into exit code 130 inside a run: the flag makes the
        # server stop all the same, and tells the client to run it itself
        terminated.append(signum)
        raise KeyboardInterrupt

    previous = {}
    if _in_main_thread():
        previous = {sig: signal.signal(sig, _terminate) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        say(f"listening on {address} (pid {os.getpid()})")
        if retain_memory and not retain_freed_memory():
            say("the C library keeps its own memory policy (not glibc)")
        if warm:
            from printability.warmup import warm_up

            res = warm_up()
            say(f"kernels loaded in {res.seconds:.1f} s")
        sock.settimeout(idle_timeout)
        while True:
            try:
                conn, _ = sock.accept()
            except TimeoutError:
                reason = f"idle for {idle_timeout:g} s"
                break
            with conn:
                conn.settimeout(_REQUEST_TIMEOUT)
                try:
                    req = recv_message(conn)
                except OSError:
                    continue
                if req is None:
                    continue
                conn.settimeout(None)
                reply, stop = _handle(req, stamp, roots)
                if terminated:
                    reply, stop = {"ok": False, "reason": "the server is stopping"}, "terminated"
                if reply.get("ok") and "rc" in reply:
                    requests += 1
                    say(f"request {requests}: {' '.join(req['argv'])} -> exit {reply['rc']}")
                with contextlib.suppress(OSError):  # the client gave up: nothing to tell it
                    send_message(conn, reply)
                if stop:
                    reason = stop
                    break
    except KeyboardInterrupt:
        reason = "terminated" if terminated else "interrupted"
    finally:
        sock.close()
        with contextlib.suppress(OSError):
            os.unlink(address)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    say(f"stopped ({reason}) after {requests} requests")
    return ServeResult(requests, reason, time.perf_counter() - t0)


def _in_main_thread() -> bool:
    """Signal handlers can only be set from the main thread (tests serve from others)."""
    import threading

    return threading.current_thread() is threading.main_thread()


def _handle(req: dict, stamp: tuple, roots: list[Path]) -> tuple[dict, str | None]:
    """The reply to one request, and why to stop afterwards (``None``: keep serving)."""
    if req.get("protocol") != PROTOCOL or req.get("version") != __version__:
        return {"ok": False, "reason": f"this server is printability {__version__} "
                                       f"(protocol {PROTOCOL})"}, None
    op = req.get("op")
    if op == "status":
        return {"ok": True, "pid": os.getpid(), "version": __version__,
                "python": sys.executable}, None
    if op == "stop":
        return {"ok": True}, "asked to stop"
    if op != "run" or not _valid_run(req):
        return {"ok": False, "reason": "expected a run, status or stop request"}, None
    if req["argv"][:1] != ["postprocess"]:
        return {"ok": False, "reason": "this server only runs postprocess"}, None
    if not os.path.isdir(req["cwd"]):
        return {"ok": False, "reason": f"{req['cwd']}: no such directory here"}, None
    for arg, ident in req["files"].items():
        if file_identities([arg], req["cwd"]).get(arg) != ident:
            return {"ok": False, "reason": f"{arg}: not the caller's file here"}, None
    if source_stamp(roots) != stamp:
        return ({"ok": False, "reason": "the installed source changed since the server "
                                        "started"}, "the installed source changed")
    rc, out, err = _run_command(req["argv"], req["cwd"], req["env"])
    return {"ok": True, "rc": rc, "stdout": out, "stderr": err}, None


def server_status(address: str | None = None) -> dict | None:
    """The running server's pid, version and Python, or ``None`` when none answers."""
    address = default_address() if address is None else address
    if address is None:
        return None
    reply = call(address, {"op": "status"}, timeout=5.0)
    return reply if reply and reply.get("ok") else None


def stop_server(address: str | None = None) -> bool:
    """Ask the server to stop once its current request is done; whether one was running."""
    address = default_address() if address is None else address
    if address is None:
        return False
    reply = call(address, {"op": "stop"}, timeout=None)
    return bool(reply and reply.get("ok"))
