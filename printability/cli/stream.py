"""``printability stream``: send a G-code file to a printer over serial (DESIGN.md §4).

A thin adapter over :class:`machine_io.Host`: parse options, connect, stream
with a progress bar, print a summary. Ctrl-C cancels cleanly (the lines in
flight finish, then the cancel sequence leaves the printer safe); a second
Ctrl-C sends M112. ``kill -USR1 <pid>`` pauses, ``kill -USR2 <pid>`` resumes.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import typer

from printability.cli.common import choices_help as _choices
from printability.options import EXTRUDER_ERROR_POLICIES, STREAM_MODES

__all__ = ["register", "stream_command"]


def stream_command(
    gcode: Path = typer.Argument(..., help="The G-code file to print."),  # noqa: B008
    port: str = typer.Option(..., "--port", "-p",
                             help="A serial device (/dev/ttyUSB0), a pty path, or a pyserial URL "
                                  "(socket://HOST:PORT, printsim://...)."),
    baud: int = typer.Option(250000, "--baud", "-b", help="Baud rate."),
    mode: str = typer.Option("auto", "--mode",
                             help=_choices(STREAM_MODES, "Flow control.")),
    error_policy: str = typer.Option("stop", "--on-error",
                                     help=_choices(EXTRUDER_ERROR_POLICIES,
                                                   "What a firmware 'Error:' does.")),
    timeout: float = typer.Option(5.0, "--timeout",
                                  help="Silence, in seconds, after which an unanswered line is "
                                       "retransmitted (busy: messages restart the clock)."),
    log: Path | None = typer.Option(None, "--log",  # noqa: B008
                                    help="Write a transcript of every line sent and received."),
    resume_from: int | None = typer.Option(None, "--resume-from",
                                           help="Start at this line of the file (1-based, as "
                                                "printed when a print stopped)."),
    restore: bool = typer.Option(True, "--restore/--no-restore",
                                 help="With --resume-from: heat, home X/Y and bring the head, "
                                      "rotary angle and E back to where the file had them."),
    home: bool = typer.Option(True, "--home/--no-home",
                              help="Home X and Y when restoring the state."),
    axis_check: bool = typer.Option(True, "--axis-check/--no-axis-check",
                                    help="Refuse G-code that drives a rotary axis the printer "
                                         "does not report."),
    json_out: Path | None = typer.Option(None, "--json",  # noqa: B008
                                         help="Write the stream report as JSON here."),
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Show a progress bar."),
) -> None:
    """Stream GCODE to the printer on PORT: line numbers and checksums, resends, busy-aware
    timeouts, pause (SIGUSR1) / resume (SIGUSR2) / cancel (Ctrl-C)."""
    from machine_io import Host, HostConfig, Transcript, load_program
    from machine_io.display import stream_progress
    from printability.cli.common import write_json_atomic
    from printability.errors import InputError, PrinterError

    config = HostConfig(mode=mode, error_policy=error_policy, baud=baud, reply_timeout=timeout,
                        check_axes=axis_check, home_on_restore=home)
    program = load_program(gcode)
    start = 0
    if resume_from is not None:
        later = [i for i, line in enumerate(program.source_lines) if line >= resume_from]
        if not later:
            raise InputError(f"--resume-from {resume_from}: {gcode} has no command at or after "
                             f"line {resume_from} (its last command is on line "
                             f"{program.source_lines[-1]})")
        start = later[0]
    show = progress and sys.stderr.isatty()

    def event(message: str) -> None:
        typer.echo(f"printability: {message}", err=True)

    with Host(port, config=config, transcript=Transcript(log), on_event=event) as host:
        firmware = host.connect()
        typer.echo(f"printer: {firmware.name or 'unnamed firmware'}"
                   f" (ADVANCED_OK {'yes' if firmware.advanced_ok else 'no'}; axes "
                   f"{''.join(sorted(firmware.axes)) or 'not reported'})", err=True)
        previous = {}
        for signum, action in ((signal.SIGUSR1, host.pause), (signal.SIGUSR2, host.resume)):
            previous[signum] = signal.signal(signum, lambda *_a, f=action: f())
        try:
            with stream_progress(gcode.name, enabled=show) as on_progress:
                report = host.stream(program, start=start, restore=resume_from is not None
                                     and restore, on_progress=on_progress,
                                     resume_file=None)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
    if json_out is not None:
        write_json_atomic(json_out, report.to_json())
    summary = (f"{report.acknowledged - report.start} of {report.total - report.start} commands "
               f"in {report.elapsed:.1f} s ({report.lines_per_second:.0f} lines/s, {report.mode}); "
               f"resends {report.resends} ({100 * report.resend_ratio:.2f} %), timeouts "
               f"{report.timeouts}, reconnects {report.reconnects}")
    if report.completed:
        typer.echo(f"printed {gcode}: {summary}")
        return
    where = (f"stopped before {program.where(report.acknowledged)}; to resume: printability "
             f"stream {gcode} --port {port} --resume-from "
             f"{program.source_lines[report.acknowledged]}"
             if report.acknowledged < len(program) else "every command was acknowledged")
    why = "cancelled by Ctrl-C" if host.interrupted else report.stopped
    raise PrinterError(f"{why}: {summary}; {where}")


def register(app: typer.Typer) -> None:
    """Add ``stream`` to the CLI."""
    app.command("stream")(stream_command)
