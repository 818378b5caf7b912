"""``printability stream``: send a G-code file to a printer over serial (docs/design.md §4).

A thin adapter over :class:`machine_io.Host`: parse options, connect, stream
with a progress display (a live bar in a terminal, a line at each quarter of
the file otherwise), print a summary. Ctrl-C, ``kill`` (SIGTERM), a closed
terminal (SIGHUP) and SIGQUIT all cancel cleanly (the lines in flight finish,
then the cancel sequence leaves the printer safe); a second one sends M112.
``kill -USR1 <pid>`` pauses, ``kill -USR2 <pid>`` resumes.
"""

from __future__ import annotations

import bisect
import contextlib
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import typer

from printability.app.cli.common import choices_help as _choices
from printability.options import EXTRUDER_ERROR_POLICIES, STREAM_MODES

__all__ = ["register", "stream_command"]

_SIGNAL_WORDS = {"SIGINT": "Ctrl-C", "SIGHUP": "SIGHUP (the terminal closed)"}
# Files above this size get a note while they are read (a few seconds per 20 MB).
_BIG_FILE = 20_000_000


@contextlib.contextmanager
def _stopped_before_streaming(port: str) -> Iterator[Callable[[], None]]:
    """Until the host streams (and handles them itself), a stop signal ends the command with
    a clear error instead of killing it silently: nothing of the file has been sent yet.
    Ctrl-C keeps Python's KeyboardInterrupt (the CLI's "interrupted"). Yields ``release``,
    which puts the previous handlers back once the stream has ended (the host restores these
    ones when it returns)."""
    from machine_io.interrupts import STOP_SIGNALS
    from printability.errors import PrinterError

    def stop(signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        raise PrinterError(f"stopped by {_SIGNAL_WORDS.get(name, name)} before streaming "
                           f"began; nothing of the file was sent to the printer on {port}")

    previous: dict[int, Any] = {}
    for signum in STOP_SIGNALS:
        if signum != signal.SIGINT:
            previous[signum] = signal.signal(signum, stop)

    def release() -> None:
        while previous:
            signum, handler = previous.popitem()
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)

    try:
        yield release
    finally:
        release()


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
                                  help="Show progress on stderr: a live bar in a terminal, a "
                                       "line at each quarter of the file otherwise."),
    connect_timeout: float = typer.Option(60.0, "--connect-timeout", min=0.1,
                                          help="Give up connecting (start banner, line-number "
                                               "handshake, firmware queries) after this many "
                                               "seconds, however much the printer talks."),
) -> None:
    """Stream GCODE to the printer on PORT: line numbers and checksums, resends, busy-aware
    timeouts, pause (SIGUSR1) / resume (SIGUSR2) / cancel (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT:
    heaters, fan and motors off)."""
    from machine_io import Host, HostConfig, Transcript, load_program
    from machine_io.display import stream_progress
    from machine_io.program import check_gcode_file
    from printability.app.cli.common import write_json_atomic
    from printability.errors import InputError, PrinterError

    config = HostConfig(mode=mode, error_policy=error_policy, baud=baud, reply_timeout=timeout,
                        check_axes=axis_check, home_on_restore=home,
                        connect_timeout=connect_timeout)
    display = None  # while streaming, events go above the progress bar

    def event(message: str) -> None:
        if display is not None:
            display.note(f"printability: {message}")
        else:
            typer.echo(f"printability: {message}", err=True)

    check_gcode_file(gcode)  # before the port: /dev/zero would be read for ever
    with _stopped_before_streaming(port) as release_signals, \
            Host(port, config=config, transcript=Transcript(log), on_event=event) as host:
        # the port first: a wrong --port is said at once, not after reading a big file
        host.open()
        # the line length is checked once the firmware is known (Klipper has no 96-byte limit)
        size = gcode.stat().st_size
        if size > _BIG_FILE:
            event(f"reading {gcode} ({size / 1e6:.0f} MB)")
        program = load_program(gcode, max_line_length=None)
        start = 0
        if resume_from is not None:
            # source_lines ascend: the first command at or after the line
            start = bisect.bisect_left(program.source_lines, resume_from)
            if start >= len(program):
                raise InputError(f"--resume-from {resume_from}: {gcode} has no command at or "
                                 f"after line {resume_from} (its last command is on line "
                                 f"{program.source_lines[-1]})")
        firmware = host.connect()
        typer.echo(f"printer: {firmware.name or 'unnamed firmware'}"
                   f" (ADVANCED_OK {'yes' if firmware.advanced_ok else 'no'}; axes "
                   f"{''.join(sorted(firmware.axes)) or 'not reported'})", err=True)
        previous = {}
        for signum, action in ((signal.SIGUSR1, host.pause), (signal.SIGUSR2, host.resume)):
            previous[signum] = signal.signal(signum, lambda *_a, f=action: f())
        try:
            with stream_progress(gcode.name, enabled=progress) as display:
                report = host.stream(program, start=start, restore=resume_from is not None
                                     and restore, on_progress=display, resume_file=None)
        finally:
            release_signals()
            display = None
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
    doubt = host.in_flight()
    if doubt:
        where += (f" (commands {doubt[0] + 1}–{doubt[-1] + 1} were sent but not acknowledged: "
                  f"they may or may not have run)")
    why = report.stopped
    if host.interrupted_by is not None:
        name = host.interrupted_by
        why = f"cancelled by {_SIGNAL_WORDS.get(name, name)}"
        if report.stopped == "cancelled":
            why += (f"; the cancel sequence ({', '.join(config.cancel_gcode)}) was sent after "
                    f"the lines in flight")
        elif report.stopped:
            why += f"; {report.stopped}"
    raise PrinterError(f"{why}: {summary}; {where}")


def register(app: typer.Typer) -> None:
    """Add ``stream`` to the CLI."""
    app.command("stream")(stream_command)
