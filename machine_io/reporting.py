"""What a stream tells: progress snapshots, the final report, where it stopped, the resume file.

Mixed into :class:`machine_io.host.Host`; the records themselves
(:class:`machine_io.session.Progress`, :class:`machine_io.session.StreamReport`)
are defined in :mod:`machine_io.session`.
"""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path
from typing import Any

from machine_io.program import Program
from machine_io.session import Progress, StreamReport
from printability.base.files import replace_file

__all__ = ["ReportingMixin"]


def _atomic_json(path: Path, doc: Any) -> None:
    """Write ``doc`` as JSON through a temporary file (the file's mode and owner kept, a new
    one 0666 less the umask)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_file(path, json.dumps(doc, indent=1).encode("utf-8"))


class ReportingMixin:
    """Progress, report and resume file of :class:`machine_io.host.Host`."""

    def _progress(self, state: str) -> Progress:
        done = self._program_acked()
        seconds = self._program.seconds
        return Progress(done, len(self._program), seconds[done - 1] if done else 0.0,
                        self._program.total_seconds, time.monotonic() - self._t0,
                        dict(self.temperatures), state, self._resends)

    def _report(self, program: Program, mode: str, elapsed: float,
                failure: str | None) -> StreamReport:
        acknowledged = self._program_acked()
        completed = failure is None and acknowledged >= len(program) and not self._cancel.is_set()
        stopped = None if completed else (failure or self._stop_reason or "stopped")
        return StreamReport(
            program.source, self.port_name, self.firmware, mode, len(program), self._start,
            acknowledged, completed, stopped, self._lines_sent, self._resends, self._stale,
            self._timeouts, self._reconnects, elapsed, self._bytes_sent,
            tuple(self._injected), tuple(self._events), dict(self.temperatures),
            tuple(self._in_doubt))

    def in_flight(self) -> tuple[int, ...]:
        """Program commands (0-based) sent but not acknowledged when the stream stopped: each
        may or may not have run, which a resume hint must say."""
        return tuple(self._owner[k] for k in range(self._acked + 1, self._max_sent + 1)
                     if self._owner[k] >= 0)

    def _where(self, report: StreamReport) -> str:
        program = self._program
        n = report.acknowledged
        in_flight = list(self.in_flight())
        if n == 0:
            text = "No command of the file was acknowledged"
        else:
            text = f"The last command acknowledged was {program.where(n - 1)}"
        if in_flight:
            text += (f"; commands {in_flight[0] + 1}–{in_flight[-1] + 1} were sent but not "
                     f"acknowledged and may or may not have run")
        if n < len(program):
            text += (f". To resume: printability stream {program.source} --port "
                     f"{self.port_name} --resume-from {program.source_lines[n]}")
        return text

    def _save_resume(self, path: Path) -> None:
        at = self._program_acked()
        doc = {"source": self._program.source, "port": self.port_name,
               "next_command": at,
               "next_line": self._program.source_lines[at] if at < len(self._program) else None,
               "total": len(self._program)}
        with contextlib.suppress(OSError):
            _atomic_json(path, doc)
