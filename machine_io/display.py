"""A rich progress bar for streaming: lines, percent, ETA, temperatures, state.

The ETA comes from the G-code's own motion-time estimate
(:attr:`machine_io.program.Program.seconds`), rescaled by the pace observed so
far (:attr:`machine_io.host.Progress.eta`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, Progress, ProgressColumn, Task, TextColumn
from rich.text import Text

from machine_io.session import Progress as StreamProgress

__all__ = ["format_temperatures", "stream_progress"]


def format_temperatures(temps: dict[str, tuple[float, float | None]]) -> str:
    """``"T 205/210 °C  B 60/60 °C"``."""
    parts = []
    for name, (actual, target) in sorted(temps.items()):
        parts.append(f"{name} {actual:.0f}" + (f"/{target:.0f}" if target is not None else "")
                     + " °C")
    return "  ".join(parts)


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "-:--:--"
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class _EtaColumn(ProgressColumn):
    def render(self, task: Task) -> Text:
        return Text(f"ETA {_clock(task.fields.get('eta'))}", style="progress.remaining")


@contextlib.contextmanager
def stream_progress(description: str, *, console: Console | None = None,
                    enabled: bool = True) -> Iterator[Callable[[StreamProgress], None]]:
    """A progress bar, yielded as an ``on_progress(Progress)`` callback for :meth:`Host.stream`.

    Parameters
    ----------
    description
        Shown left of the bar (the file name).
    console
        Where to draw (default: stderr).
    enabled
        False yields a callback that does nothing.
    """
    if not enabled:
        yield lambda p: None
        return
    console = console or Console(stderr=True)
    columns = (TextColumn("[bold]{task.description}"), BarColumn(),
               TextColumn("{task.completed:,.0f}/{task.total:,.0f} lines"),
               TextColumn("{task.percentage:>5.1f}%"), _EtaColumn(),
               TextColumn("{task.fields[temps]}"), TextColumn("[yellow]{task.fields[state]}"))
    with Progress(*columns, console=console, transient=False) as bar:
        task = bar.add_task(description, total=None, eta=None, temps="", state="")

        def update(p: StreamProgress) -> None:
            extra = p.state if p.state != "streaming" else ""
            if p.resends:
                extra = (extra + f" {p.resends} resends").strip()
            bar.update(task, completed=p.done, total=p.total, eta=p.eta,
                       temps=format_temperatures(p.temperatures), state=extra)

        yield update
