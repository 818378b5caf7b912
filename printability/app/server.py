"""``printability serve``: a warm process that runs the slicer plug-in's post-processing.

The ``printability-postprocess`` entry point first offers its run to this
server (:func:`printability.app.server_client.run_remote`, where the address,
the messages, the deadlines and the fall-back rule are documented) and runs
locally only when there is none. The server runs each request as the command
line would (:func:`printability.app.cli.main.run`), in its own process, one at a
time in the order they arrive, with the request's working directory and its
``SLIC3R_*``/``PRINTABILITY_*`` variables, and returns the exit code and what
the command printed. The output file is therefore byte for byte what a local
run writes, and an error is the same one paragraph with exit code 1.

It declines (and the client runs locally) when the client's version is not
its own, when a file the command names is not the one the client sees (same
device, inode, size and time: a sandbox or container with its own /tmp), when
the client's ticket is gone (it stopped waiting), and for any command but
``postprocess``; it declines and stops when any source file of the installed
packages changed since it started (an edited or upgraded install), so it
never runs code other than what is on disk.

Nothing a client sends stops it. Each connection has its own thread, which
reads the request within :data:`_REQUEST_TIMEOUT` s and
:data:`printability.app.server_connections.MAX_REQUEST` bytes and checks every
field (:func:`check_request`); anything else is
answered with a one-line refusal, and logged. Only the work itself is
serialized, in the thread that called :func:`serve` (it swaps the process's
environment, directory and standard streams): a silent or slow client holds
its own thread and nothing else. While a request waits or runs, its thread
sends the client a heartbeat a second. A run removes the client's ticket just
before it replaces the first file (:class:`_WriteGate`): when the client took
it first (it stopped waiting and runs the command itself), the run writes
nothing. The connections' side (reading, checking, queueing, heartbeats) is
:mod:`printability.app.server_connections`; this module runs the queued requests.

Complexity: per request the work itself, plus a stat of the packages' source
files (about a millisecond) and a JSON round trip of the command's output.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import io
import os
import queue
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from printability.app.server_client import (
    ServerAddressError,
    call,
    default_address,
    file_identities,
    forwarded,
    secure_dir,
    take_ticket,
)
from printability.app.server_connections import (
    STOPPING,
    TICKET_NAME,
    Clients,
    Job,
    check_request,
    printable,
)
from printability.errors import PrintabilityOSError

__all__ = ["ServeResult", "check_request", "retain_freed_memory", "serve", "server_status",
           "source_stamp", "stop_server"]

_PACKAGES = ("printability", "gcode", "machine_io", "plugin", "simulators")
_REQUEST_TIMEOUT = 10.0  # s to receive a whole request once connected (then it is refused)
_TICKET_AGE = 86_400.0  # s after which a ticket left behind (its client killed) is removed
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
    from printability.app.cli.main import run as cli_run  # not main: it would ask this server

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




# --- the write gate ---------------------------------------------------------------------

_CACHE_SUFFIXES = (".nbi", ".nbc")  # numba's cache: written during a run, not its output
_gate: _WriteGate | None = None
_hooked = False


class _WriteGate:
    """While a run is on, its thread's first ``os.replace``/``os.rename`` (numba's cache
    files aside) must first remove the client's ticket: removed, the run writes; already
    gone, or the client hung up, the rename fails (``ECANCELED``) and the command reports
    its file unchanged. The check is an audit hook (``sys.addaudithook``): every rename of
    the thread passes it, however the code reaches ``os.replace``."""

    def __init__(self, ticket: str, client_left: Callable[[], bool]):
        self.ticket = ticket
        self.client_left = client_left
        self.thread = threading.get_ident()
        self.owned = False  # the ticket was ours: the run wrote
        self.refused = False  # a write was refused: the client had stopped waiting

    def check(self) -> None:
        if self.owned:
            return
        if not self.refused:
            if self.client_left():
                take_ticket(self.ticket)  # nobody to decide any more: clean it up
            elif take_ticket(self.ticket):
                self.owned = True
                return
            self.refused = True
        raise OSError(errno.ECANCELED, "the client stopped waiting for the server")

    @contextlib.contextmanager
    def active(self):
        global _gate
        _install_hook()
        _gate = self
        try:
            yield self
        finally:
            _gate = None


def _audit(event: str, args: tuple) -> None:
    if event != "os.rename":
        return
    gate = _gate
    if gate is None or gate.thread != threading.get_ident():
        return
    try:
        if os.fsdecode(args[1]).endswith(_CACHE_SUFFIXES):
            return
    except (TypeError, IndexError):
        pass
    gate.check()


def _install_hook() -> None:
    """Add :func:`_audit` once per process (an audit hook cannot be removed; outside a run
    it returns at once)."""
    global _hooked
    if not _hooked:
        sys.addaudithook(_audit)
        _hooked = True


def _sweep_tickets(folder: str) -> None:
    """Remove the tickets older than a day in ``folder`` (a client killed before its server
    read the request leaves one)."""
    limit = time.time() - _TICKET_AGE
    with contextlib.suppress(OSError), os.scandir(folder) as entries:
        for e in entries:
            if TICKET_NAME.match(e.name):
                with contextlib.suppress(OSError):
                    if e.stat(follow_symlinks=False).st_mtime < limit:
                        os.unlink(e.path)


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




# --- the server -------------------------------------------------------------------------

def serve(
    *,
    address: str | None = None,
    idle_timeout: float | None = None,
    warm: bool = True,
    watch: Iterable[Path] | None = None,
    on_event: Callable[[str], None] | None = None,
    retain_memory: bool = False,
    request_timeout: float = _REQUEST_TIMEOUT,
) -> ServeResult:
    """Serve post-processing requests until stopped, idle or stale.

    Parameters
    ----------
    address
        The socket path (default: :func:`printability.app.server_client.default_address`).
    idle_timeout
        Stop after this many seconds without a connection (``None``: never).
    warm
        Load the plug-in's compiled kernels before the first request
        (:func:`printability.app.warmup.warm_up`: seconds when cached, about a
        minute right after an install); requests arriving meanwhile wait.
    watch
        Directories whose ``.py`` files are compared before each run (default:
        the installed packages'); any change stops the server.
    on_event
        Called with a one-line message on start, per request, per refused
        request and on stop (from the calling thread only, never during a run).
    retain_memory
        Keep freed memory for the next request (:func:`retain_freed_memory`):
        process-wide, so for a process that only serves.
    request_timeout
        Seconds a client has, once connected, to send its whole request.

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
    folder = os.path.abspath(os.path.dirname(address) or ".")
    _sweep_tickets(folder)
    state = _Serving(Clients(sock, folder, request_timeout), stamp, roots, say)
    with _interrupting_signals(state.terminated):
        try:
            _start(state, address, retain_memory=retain_memory, warm=warm)
            _serve_jobs(state, idle_timeout)
        except KeyboardInterrupt:
            state.reason = "terminated" if state.terminated else "interrupted"
        finally:
            _shut_down(state, sock, address)
    say(f"stopped ({state.reason}) after {state.requests} requests")
    return ServeResult(state.requests, state.reason, time.perf_counter() - t0)


@dataclass(eq=False)
class _Serving:
    """The serving thread's state: what it serves with, and how far it got."""

    clients: Clients
    stamp: tuple
    roots: list[Path]
    say: Callable[[str], None]
    terminated: list[int] = field(default_factory=list)  # the signals that stop it
    requests: int = 0
    reason: str = "stopped"
    job: Job | None = None  # the job being handled, finished on the way out if still open


@contextlib.contextmanager
def _interrupting_signals(terminated: list[int]) -> Iterator[None]:
    """SIGTERM and SIGINT raise KeyboardInterrupt in the serving thread (the main thread
    only), noted in ``terminated``; the previous handlers come back afterwards."""

    def _terminate(signum, _frame):
        # the CLI turns KeyboardInterrupt into exit code 130 inside a run: the flag makes the
        # server stop all the same, and tells the client to run it itself
        terminated.append(signum)
        raise KeyboardInterrupt

    previous = {}
    if _in_main_thread():
        previous = {sig: signal.signal(sig, _terminate) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _start(state: _Serving, address: str, *, retain_memory: bool, warm: bool) -> None:
    """Take connections, then set the memory policy and load the kernels (requests arriving
    meanwhile wait in the queue)."""
    state.clients.start()
    say = state.say
    say(f"listening on {address} (pid {os.getpid()})")
    if retain_memory and not retain_freed_memory():
        say("the C library keeps its own memory policy (not glibc)")
    if warm:
        from printability.app.warmup import warm_up

        res = warm_up()
        say(f"kernels loaded in {res.seconds:.1f} s")


def _serve_jobs(state: _Serving, idle_timeout: float | None) -> None:
    """Run the queued jobs one at a time until idle, asked to stop, or stale."""
    say = state.say
    while True:
        state.job = None
        item = _next(state.clients, idle_timeout)
        if item is None:
            state.reason = f"idle for {idle_timeout:g} s"
            return
        if isinstance(item, str):
            say(item)
            continue
        job = state.job = item
        if job.op == "stop":
            job.finish({"ok": True})
            state.reason = "asked to stop"
            return
        try:
            reply, stop = _handle(job, state.stamp, state.roots, say)
        except Exception:  # a bug: say so, decline, keep serving
            say("error while running a request:\n" + traceback.format_exc().rstrip())
            reply, stop = {"ok": False, "reason": "the server failed (see its log)"}, None
        if state.terminated:
            stop = "terminated"
            if not job.wrote:  # done and written: the client takes the run's reply
                reply = STOPPING
        if reply is not None and "rc" in reply:
            state.requests += 1
            note = "; nothing written: the client had stopped waiting" if job.refused else ""
            say(f"request {state.requests}: {printable(job.req['argv'])} -> exit "
                f"{reply['rc']}{note}")
        job.finish(reply or STOPPING)
        if stop:
            state.reason = stop
            return


def _shut_down(state: _Serving, sock: socket.socket, address: str) -> None:
    """Stop taking connections, remove the socket, and decline what is still queued."""
    clients = state.clients
    clients.stop()
    sock.close()
    with contextlib.suppress(OSError):
        os.unlink(address)
    if state.job is not None:
        state.job.finish(STOPPING)
    for item in _drain(clients.jobs):
        if isinstance(item, str):
            state.say(item)
        else:
            item.finish(STOPPING)


def _next(clients: Clients, idle_timeout: float | None) -> Job | str | None:
    """The next queued job or log line; ``None`` once idle for ``idle_timeout`` s."""
    while True:
        wait = None
        if idle_timeout is not None:
            idle = clients.idle_for()
            if idle is not None and idle >= idle_timeout:
                return None
            wait = 0.1 if idle is None else max(idle_timeout - idle, 0.01)
        try:
            return clients.jobs.get(timeout=wait)
        except queue.Empty:
            continue


def _drain(jobs: queue.SimpleQueue) -> list:
    out = []
    while True:
        try:
            out.append(jobs.get_nowait())
        except queue.Empty:
            return out


def _in_main_thread() -> bool:
    """Signal handlers can only be set from the main thread (tests serve from others)."""
    return threading.current_thread() is threading.main_thread()


def _handle(job: Job, stamp: tuple, roots: list[Path],
            say: Callable[[str], None]) -> tuple[dict | None, str | None]:
    """Run ``job`` (a checked run request): its reply (``None``: its client left), and why to
    stop afterwards (``None``: keep serving)."""
    req = job.req
    if job.left:
        take_ticket(job.ticket)
        say(f"declined {printable(req['argv'])}: the client left before its turn")
        return None, None
    reply, stop = _decline(req, job.ticket, stamp, roots)
    if reply is not None:
        say(f"declined {printable(req['argv'])}: {reply['reason']}")
        return reply, stop
    with _WriteGate(job.ticket, lambda: job.left).active() as gate:
        rc, out, err = _run_command(req["argv"], req["cwd"], req["env"])
    job.wrote, job.refused = gate.owned, gate.refused
    return {"ok": True, "rc": rc, "stdout": out, "stderr": err}, None


def _decline(req: dict, ticket: str, stamp: tuple,
             roots: list[Path]) -> tuple[dict | None, str | None]:
    """Why a checked run request is not run here (``None``: it is), and why to stop."""
    if not os.path.exists(ticket):  # the client took it back (or sees another folder)
        return {"ok": False, "reason": "the ticket is gone: the client stopped waiting"}, None
    if not os.path.isdir(req["cwd"]):
        return {"ok": False, "reason": f"{req['cwd']}: no such directory here"}, None
    for arg, ident in req["files"].items():
        if file_identities([arg], req["cwd"]).get(arg) != ident:
            return {"ok": False, "reason": f"{arg}: not the caller's file here"}, None
    if source_stamp(roots) != stamp:
        return ({"ok": False, "reason": "the installed source changed since the server "
                                        "started"}, "the installed source changed")
    return None, None


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
