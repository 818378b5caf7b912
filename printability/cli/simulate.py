"""``printability simulate``: start the virtual T-T-R printer (DESIGN.md §4).

A thin adapter over :mod:`simulators`: build the configuration, start a pty
or TCP server, print the port on the first line of stdout, run until Ctrl-C /
SIGTERM (or ``--duration``), then write the deposition record. ``kill -USR1
<pid>`` writes the record at once without stopping.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

import typer

from printability.cli.common import choices_help as _choices
from printability.options import FIRMWARE_PROFILES, SIM_CLOCKS

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
    machine: str = typer.Option("ttr", "--machine", help="Machine SPEC or profile (rotary "
                                                         "letter and limits, bed, feed policy)."),
    nozzle: str = typer.Option("circle:d=0.4", "--nozzle", help="Nozzle SPEC whose footprint "
                                                                "the deposition sweeps."),
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
) -> None:
    """Start the virtual T-T-R printer; its port is the first line of stdout."""
    from printability.errors import InputError
    from simulators import make_config
    from simulators.transports import Link, PtyServer, TcpServer

    if pty and tcp is not None:
        raise InputError("choose one transport: --pty or --tcp PORT, not both")
    if duration is not None and not duration > 0:
        raise InputError(f"--duration must be a positive number of seconds; found {duration}")
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

    old = {s: signal.signal(s, h) for s, h in ((signal.SIGTERM, _stop), (signal.SIGINT, _stop),
                                               (signal.SIGUSR1, _write_now))}
    try:
        server.start()
        print(server.url if isinstance(server, TcpServer) else server.path, flush=True)
        stop.wait(duration)
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


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` subcommand to the CLI."""
    app.command("simulate")(simulate_command)
