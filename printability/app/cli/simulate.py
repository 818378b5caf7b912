"""``printability simulate``: start the virtual T-T-R printer (docs/design.md §4).

A thin adapter over :mod:`simulators`: build the configuration, start a pty
or TCP server, print the port on the first line of stdout, run until Ctrl-C /
SIGTERM / SIGHUP (or ``--duration``), then write the deposition record. ``kill -USR1
<pid>`` writes the record at once without stopping.

While it runs it says on stderr when a host connects or leaves, and (in a
terminal, or with ``--status-interval``) every few seconds what the printer
is doing: commands executed, position, layer, heaters. stdout keeps only the
port, which scripts read from its first line.
"""

from __future__ import annotations

import math
import queue
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from printability.app.cli.common import choices_help as _choices
from printability.app.cli.common import spec_epilog
from printability.options import FIRMWARE_PROFILES, SIM_CLOCKS

if TYPE_CHECKING:
    from simulators.transports import Link

__all__ = ["register", "simulate_command"]


def _fw_overrides(items: list[str]) -> dict[str, object]:
    from printability.errors import InputError

    out: dict[str, object] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq:
            raise InputError(f"--fw expects KEY=VALUE (e.g. planner_buffer=8); found {item!r}")
        v = value.strip().lower()
        if v in ("true", "false", "yes", "no", "on", "off"):
            out[key.strip()] = v in ("true", "yes", "on")
            continue
        try:
            out[key.strip()] = int(value) if value.strip().lstrip("+-").isdigit() else float(value)
        except ValueError:
            raise InputError(f"--fw {key}= expects a number or true/false; "
                             f"found {value!r}") from None
    return out


def simulate_command(
    pty: bool = typer.Option(False, "--pty", help="Serve on a pseudo-terminal (the default)."),
    tcp: int | None = typer.Option(None, "--tcp", help="Serve on TCP 127.0.0.1:PORT instead "
                                                       "(0 picks a free port)."),
    link: Path | None = typer.Option(None, "--link",  # noqa: B008
                                     help="Also make this symlink point at the pty."),
    profile: str = typer.Option("marlin", "--profile",
                                help=_choices(FIRMWARE_PROFILES, "Firmware profile.")),
    machine: str = typer.Option("ttr", "--machine", metavar="SPEC",
                                help="The machine (rotary letter and limits, bed, feed "
                                     "policy; SPECs below)."),
    nozzle: str = typer.Option("circle:d=0.4", "--nozzle", metavar="SPEC",
                               help="The nozzle whose footprint the deposition sweeps."),
    clock: str = typer.Option("real", "--clock",
                              help=_choices(SIM_CLOCKS, "Time base.")),
    baud: int | None = typer.Option(None, "--baud", help="Pace the wire at this many bits per "
                                                         "second (10 bits per byte)."),
    faults: str = typer.Option("", "--faults", help="Faults to inject, e.g. "
                                                    "'drop-ok@12,corrupt~0.01,stall@40:3'."),
    seed: int = typer.Option(0, "--seed", help="Seed of the random faults."),
    fw: list[str] = typer.Option([], "--fw", help="Firmware setting KEY=VALUE, e.g. "  # noqa: B008
                                                  "planner_buffer=8 (repeatable)."),
    record: Path | None = typer.Option(None, "--record",  # noqa: B008
                                       help="Write the deposition record (JSON) here on exit "
                                            "and on SIGUSR1."),
    target: Path | None = typer.Option(None, "--target",  # noqa: B008
                                       help="Layers the part should have (any input analyze "
                                            "reads); the record reports material outside them."),
    duration: float | None = typer.Option(None, "--duration",
                                          help="Stop after this many seconds."),
    status_interval: float | None = typer.Option(
        None, "--status-interval",
        help="Print a status line (commands executed, position, layer, heaters) on stderr "
             "every this many seconds while the printer is busy; default 5 when stderr is a "
             "terminal, none otherwise; 0 turns it off."),
    quiet: bool = typer.Option(False, "--quiet", "-q",
                               help="No connection or status lines; only the final summary."),
) -> None:
    """Start the virtual T-T-R printer; its port is the first line of stdout. --clock sim
    runs a print as fast as the host sends it (the real clock takes the print's own time)."""
    from printability.errors import InputError
    from simulators import make_config
    from simulators.transports import Link, PtyServer, TcpServer

    if pty and tcp is not None:
        raise InputError("choose one transport: --pty or --tcp PORT, not both")
    if duration is not None and not (duration > 0 and math.isfinite(duration)):
        raise InputError(f"--duration must be a positive number of seconds; found {duration}")
    if status_interval is not None and not (status_interval >= 0
                                            and math.isfinite(status_interval)):
        raise InputError(f"--status-interval must be a number of seconds, 0 or more; found "
                         f"{status_interval}")
    if quiet:
        status_interval = 0.0
    elif status_interval is None:
        status_interval = 5.0 if sys.stderr.isatty() else 0.0
    layers = None
    if target is not None:
        from printability.sources import load_layers

        layers = load_layers(target)
    cfg = make_config(profile=profile, machine=machine, nozzle=nozzle, clock=clock, baud=baud,
                      faults=faults, seed=seed, record=str(record) if record else None,
                      target=layers, firmware=_fw_overrides(fw))
    sim = Link(cfg)
    server = (TcpServer(sim, port=tcp) if tcp is not None
              else PtyServer(sim, symlink=str(link) if link else None))
    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    def _write_now(signum: int, frame: object) -> None:
        if record is not None:
            with sim.lock:
                sim.firmware.write_record()

    # A closed terminal (SIGHUP) ends it like Ctrl-C and kill: with the record written.
    old = {s: signal.signal(s, h) for s, h in ((signal.SIGTERM, _stop), (signal.SIGINT, _stop),
                                               (signal.SIGHUP, _stop),
                                               (signal.SIGUSR1, _write_now))}
    # The server thread only queues its messages: a stderr nobody reads must block at most
    # this thread, never the printer.
    events: queue.SimpleQueue[str] = queue.SimpleQueue()
    if not quiet:
        server.on_event = events.put
    try:
        server.start()
        print(server.url if isinstance(server, TcpServer) else server.path, flush=True)
        _serve_until(stop, sim, events, duration=duration, status_interval=status_interval)
    finally:
        server.stop()
        for s, h in old.items():
            signal.signal(s, h)
    if server.error is not None:
        raise server.error
    st = sim.firmware.stats
    print(f"simulate: {st.executed} commands executed, {st.resends} resends, "
          f"{st.moves} moves, motion time {st.motion_time:.1f} s"
          + (f", {len(st.lost)} acknowledged moves lost in resets" if st.lost else "")
          + (f"; record written to {record}" if record else ""), file=sys.stderr)


def _serve_until(stop: threading.Event, sim: Link, events: queue.SimpleQueue[str], *,
                 duration: float | None, status_interval: float) -> None:
    """Wait for ``stop`` (or ``duration``), printing the server's messages and, every
    ``status_interval`` seconds while the printer works, its status line."""
    end = None if duration is None else time.monotonic() + duration
    next_status = time.monotonic() + status_interval
    last = sim.status() if status_interval > 0 else None  # a printer never used says nothing
    while True:
        now = time.monotonic()
        wait = 0.2 if end is None else min(0.2, end - now)
        stopping = wait <= 0 or stop.wait(wait)
        _print_events(events)
        if status_interval > 0 and (stopping or time.monotonic() >= next_status):
            # On the way out too: the last status is where the printer was left.
            next_status = time.monotonic() + status_interval
            line = sim.status()
            if line != last:  # an idle printer is not reported again and again
                last = line
                print(f"simulate: {line}", file=sys.stderr, flush=True)
        if stopping:
            return


def _print_events(events: queue.SimpleQueue[str]) -> None:
    while True:
        try:
            message = events.get_nowait()
        except queue.Empty:
            return
        print(f"simulate: {message}", file=sys.stderr, flush=True)


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` subcommand to the CLI."""
    app.command("simulate", epilog=spec_epilog())(simulate_command)
