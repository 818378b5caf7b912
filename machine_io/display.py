"""Progress of a stream for people: a live bar in a terminal, a few plain lines elsewhere.

The live bar is one line, fitted to the terminal's width: file name, bar,
lines, percent and ETA, then the state (paused, reconnecting, resends) and
the temperatures while there is room; a narrow terminal loses the optional
fields and then the bar, never wraps. The ETA comes from the G-code's own
motion-time estimate (:attr:`machine_io.program.Program.seconds`), rescaled
by the pace observed so far (:attr:`machine_io.session.Progress.eta`).

Every field may be unknown at some moment — before the first progress report
(no total yet), at the start (no pace, so no ETA), on a stalled link or while
reconnecting, for a file whose estimate overflows (an infinite or NaN ETA) —
and each is drawn as "unknown" then, never by formatting ``None``: rich's
``TextColumn`` format strings raised on ``None`` when the first frame was
drawn, which is how ``stream`` crashed in every terminal.

When the output is not a terminal (a pipe, a log file, ``TERM=dumb``) a
redrawn bar would write a frame ten times a second; the plain display writes
one line at each quarter of the file instead.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from collections.abc import Iterator
from typing import TextIO

from rich.console import Console, ConsoleOptions, RenderResult
from rich.live import Live
from rich.text import Text

from machine_io.session import Progress as StreamProgress

__all__ = ["StreamDisplay", "format_clock", "format_temperatures", "stream_progress"]

_UNKNOWN_CLOCK = "-:--:--"
# 100 hours: past this an ETA says nothing useful and would only widen the line.
_MAX_CLOCK = 100 * 3600
_MIN_BAR = 10  # narrower than this, the bar says nothing the percentage does not
_MAX_BAR = 40
_MAX_NAME = 30


def _finite(value: object) -> float | None:
    """``value`` as a float if it is a finite number, else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def format_temperatures(temps: dict[str, tuple[float, float | None]]) -> str:
    """``"B 60/60 °C  T 205/210 °C"``; a reading that is not a finite number shows as ``?``."""
    def deg(v: float | None) -> str:
        f = _finite(v)
        return "?" if f is None else f"{f:.0f}"

    parts = []
    for name, (actual, target) in sorted(temps.items()):
        parts.append(f"{name} {deg(actual)}" + (f"/{deg(target)}" if target is not None else "")
                     + " °C")
    return "  ".join(parts)


def format_clock(seconds: float | None) -> str:
    """``"1:02:03"``; ``"-:--:--"`` when unknown (None, NaN, infinite or negative)."""
    s = _finite(seconds)
    if s is None or s < 0:
        return _UNKNOWN_CLOCK
    if s >= _MAX_CLOCK:
        return ">99:59:59"
    t = round(s)
    return f"{t // 3600}:{t // 60 % 60:02d}:{t % 60:02d}"


def _count(n: object) -> str:
    f = _finite(n)
    return "?" if f is None else f"{f:,.0f}"


def _percent(done: object, total: object) -> float | None:
    d, t = _finite(done), _finite(total)
    if d is None or t is None or t <= 0:
        return None
    return max(0.0, min(100.0, 100.0 * d / t))


def _state_text(p: StreamProgress) -> str:
    extra = p.state if p.state != "streaming" else ""
    if p.resends:
        extra = (extra + f" {p.resends} resends").strip()
    return extra


class _BarLine:
    """The live line; rendered by rich's refresh thread from the latest snapshot."""

    def __init__(self, description: str) -> None:
        self.description = description
        self.snapshot: StreamProgress | None = None  # replaced whole: no lock needed

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield self.line(options.max_width,
                        color=not console.no_color and console.color_system is not None)

    def line(self, width: int, *, color: bool = True) -> Text:
        """The line for a terminal ``width`` columns wide (without colours the rest of the
        bar is drawn thin, so that the filled part still shows)."""
        p = self.snapshot
        done, total = (p.done, p.total) if p is not None else (0, None)
        pct = _percent(done, total)
        right = Text()
        right.append(f" {_count(done)}/{_count(total)} lines")
        right.append("  -.-%" if pct is None else f" {pct:5.1f}%", style="progress.percentage")
        right.append(f" ETA {format_clock(p.eta if p is not None else None)}",
                     style="progress.remaining")
        name = self.description
        if len(name) > _MAX_NAME:
            name = name[:_MAX_NAME - 1] + "…"
        # Optional fields, most telling first, while the bar keeps its minimum width.
        for text, style in ((_state_text(p) if p else "", "yellow"),
                            (format_temperatures(p.temperatures) if p else "", "")):
            if text and len(name) + 1 + _MIN_BAR + len(right) + 1 + len(text) <= width:
                right.append(" " + text, style=style)
        out = Text(name, style="bold")
        room = width - len(name) - 1 - len(right)
        if room >= _MIN_BAR:
            bar = min(room, _MAX_BAR)
            filled = 0 if pct is None else round(bar * pct / 100.0)
            out.append(" ")
            out.append("━" * filled, style="bar.finished" if pct == 100.0 else "bar.complete")
            out.append(("━" if color else "─") * (bar - filled), style="bar.back")
        out.append_text(right)
        out.truncate(max(width, 1), overflow="ellipsis")
        return out


class StreamDisplay:
    """What :func:`stream_progress` yields: an ``on_progress`` callback with a :meth:`note`.

    Call it with a :class:`machine_io.session.Progress`; :meth:`note` prints a
    one-line message above a live bar (or plainly) without breaking it. A
    display that cannot write any more (a closed pipe, a terminal that hung up)
    goes quiet instead of raising into the host: a display must never stop a
    print, least of all the cancel sequence that follows a hang-up.
    """

    def __init__(self, *, mode: str, description: str, stream: TextIO | None = None,
                 live: Live | None = None, line: _BarLine | None = None) -> None:
        self.mode = mode
        self.description = description
        self._stream = stream
        self._live = live
        self._line = line
        self._next_quarter = 1
        self._broken = False

    def __call__(self, p: StreamProgress) -> None:
        if self._broken or self.mode == "off":
            return
        if self._line is not None:
            self._line.snapshot = p  # drawn by the live display's own refresh
            return
        if self.mode == "plain":
            try:
                self._plain(p)
            except (OSError, ValueError):
                self._broken = True

    def _plain(self, p: StreamProgress) -> None:
        pct = _percent(p.done, p.total)
        if pct is None or p.state == "done":
            return
        quarter = int(pct // 25)
        if quarter < self._next_quarter or quarter >= 4:
            return
        self._next_quarter = quarter + 1
        eta = p.eta
        self._write(f"{self.description}: {pct:.0f} % ({p.done:,} of {p.total:,} commands)"
                    + (f", ETA {format_clock(eta)}" if eta is not None else ""))

    def note(self, message: str) -> None:
        """Print one line (an event of the stream) without disturbing the bar."""
        if self._broken:
            return
        try:
            if self._live is not None:
                self._live.console.print(Text(message), soft_wrap=True)
            else:
                self._write(message)
        except (OSError, ValueError):
            self._broken = True

    def _write(self, line: str) -> None:
        stream = self._stream or sys.stderr
        stream.write(line + "\n")
        stream.flush()


def _terminal(stream: TextIO) -> bool:
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError, OSError):
        return False
    return tty and os.environ.get("TERM", "") != "dumb"


@contextlib.contextmanager
def stream_progress(description: str, *, console: Console | None = None,
                    enabled: bool = True, mode: str = "auto") -> Iterator[StreamDisplay]:
    """A progress display, yielded as an ``on_progress(Progress)`` callback for
    :meth:`machine_io.host.Host.stream`.

    Parameters
    ----------
    description
        Shown left of the bar (the file name).
    console
        Where to draw (default: stderr); ``"auto"`` then asks it whether it is a terminal.
    enabled
        False yields a display that draws nothing (its :meth:`StreamDisplay.note`
        still prints).
    mode
        ``"live"`` (a redrawn bar), ``"plain"`` (a line at 25, 50 and 75 %), or
        ``"auto"``: live on a terminal, plain otherwise.

    Yields
    ------
    StreamDisplay
        The callback.
    """
    if mode not in ("auto", "live", "plain"):
        raise ValueError(f"mode must be 'auto', 'live' or 'plain'; got {mode!r}")
    stream = console.file if console is not None else sys.stderr
    if not enabled:
        yield StreamDisplay(mode="off", description=description, stream=stream)
        return
    if mode == "auto":
        if console is not None:
            live_ok = console.is_terminal and not console.is_dumb_terminal
        else:
            live_ok = _terminal(stream)
        mode = "live" if live_ok else "plain"
    if mode == "plain":
        yield StreamDisplay(mode="plain", description=description, stream=stream)
        return
    console = console or Console(stderr=True)
    line = _BarLine(description)
    live = Live(line, console=console, refresh_per_second=10, transient=False)
    try:
        live.start()
    except (OSError, ValueError):
        yield StreamDisplay(mode="off", description=description, stream=stream)
        return
    try:
        yield StreamDisplay(mode="live", description=description, live=live, line=line)
    finally:
        # A terminal that hung up cannot take the last frame: that must not turn a clean
        # cancel into a traceback.
        with contextlib.suppress(OSError, ValueError):
            live.stop()
