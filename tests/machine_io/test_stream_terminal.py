"""``printability stream`` as a person sees it: in a real terminal with the progress bar on,
and with stderr piped (a few plain lines, no redrawn frames); the display's fields when they
are unknown (no total yet, no pace, an estimate that overflowed)."""

from __future__ import annotations

import io
import math
import re
import subprocess

import pytest
from _cli_helpers import PRINTABILITY, ROOT, Simulator, env, run_in_terminal, screen
from rich.console import Console

from machine_io.display import format_clock, format_temperatures, stream_progress
from machine_io.session import Progress


def _part(tmp_path, n: int = 3000):
    path = tmp_path / "part.gcode"
    path.write_text("; a part\nG28\nG90\n" + "".join(f"G1 X{i % 50} Y{i % 7} F3000\n"
                                                    for i in range(n)))
    return path, n + 2


@pytest.mark.parametrize("columns", [80, 120])
def test_stream_in_a_terminal_shows_the_bar_and_the_summary(tmp_path, columns):
    gcode, total = _part(tmp_path)
    with Simulator(tmp_path / "record.json") as sim:
        status, out = run_in_terminal([*PRINTABILITY, "stream", str(gcode), "--port", sim.port],
                                      columns=columns, rows=30)
    shown = screen(out)
    text = "\n".join(shown)
    assert status == 0, text
    assert "Traceback" not in out and "Error" not in out, text
    bars = [line for line in shown if line.startswith("part.gcode") and " lines" in line]
    assert bars, text
    # The last frame stays on the screen: one line, within the terminal's width.
    assert re.search(rf"━ {total:,}/{total:,} lines\s+100\.0%\s+ETA 0:00:00", bars[-1]), bars
    assert len(bars[-1]) <= columns
    assert f"printed {gcode}: {total} of {total} commands" in " ".join(text.split())
    # The simulator ran the file.
    assert sim.log()[:total] == ["G28", "G90", *(f"G1 X{i % 50} Y{i % 7} F3000"
                                                   for i in range(total - 2))]


def test_piped_progress_is_a_few_plain_lines(tmp_path):
    gcode, total = _part(tmp_path)
    with Simulator(tmp_path / "record.json") as sim:
        r = subprocess.run([*PRINTABILITY, "stream", str(gcode), "--port", sim.port],
                           capture_output=True, text=True, timeout=120, cwd=ROOT, env=env())
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr and "\x1b" not in r.stderr
    lines = r.stderr.splitlines()
    assert all(line.strip() for line in lines), lines  # no blank lines
    progress = [line for line in lines if line.startswith("part.gcode:")]
    assert 1 <= len(progress) <= 3, lines
    assert all(re.fullmatch(r"part\.gcode: \d\d % \([\d,]+ of [\d,]+ commands\)"
                            r"(, ETA \d+:\d\d:\d\d)?", line) for line in progress), progress
    assert len(lines) <= 6, lines
    assert f"{total} of {total} commands" in r.stdout


def _frames(updates: list[Progress], width: int = 100) -> str:
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=width, color_system=None)
    with stream_progress("part.gcode", console=console) as display:
        for p in updates:
            display(p)
        display.note("printability: the link was lost: reconnecting")
    return buf.getvalue()


def test_the_bar_draws_every_field_while_it_is_unknown():
    # The first frame is drawn before any progress report: no total yet. Then: the start
    # (no pace), a stalled link (no command acknowledged for a long time), a file whose
    # motion estimate overflowed (inf and NaN), a reconnect, the end.
    inf, nan = math.inf, math.nan
    updates = [
        Progress(0, 500, 0.0, 120.0, 0.0, {}, "streaming", 0),
        Progress(0, 500, 0.0, 120.0, 600.0, {"T": (21.0, None)}, "reconnecting", 0),
        Progress(10, 500, inf, inf, 5.0, {"T": (nan, 210.0)}, "streaming", 2),
        Progress(10, 500, 5.0, nan, 5.0, {}, "streaming", 0),
        Progress(250, 500, 60.0, 120.0, 30.0, {"T": (205.0, 210.0), "B": (60.0, 60.0)},
                 "streaming", 0),
        Progress(500, 500, 120.0, 120.0, 61.0, {}, "done", 3),
    ]
    out = _frames(updates)
    shown = screen(out)
    assert any("the link was lost" in line for line in shown)
    assert re.search(r"500/500 lines\s+100\.0%\s+ETA 0:00:00", "\n".join(shown)), shown


def test_a_bar_that_never_got_a_report_still_closes_cleanly():
    shown = screen(_frames([]))
    assert any(re.search(r"0/\? lines\s+-\.-%\s+ETA -:--:--", line) for line in shown), shown


def test_unknown_values_are_shown_as_unknown():
    for value in (None, math.nan, math.inf, -math.inf, -5.0, "soon"):
        assert format_clock(value) == "-:--:--"
    assert format_clock(0.4) == "0:00:00"
    assert format_clock(3723) == "1:02:03"
    assert format_clock(1e300) == ">99:59:59"
    assert format_temperatures({"T": (math.nan, 210.0), "B": (60.4, None)}) == \
        "B 60 °C  T ?/210 °C"
    # The ETA itself is never NaN, infinite or negative.
    assert Progress(10, 500, 5.0, math.nan, 5.0, {}, "streaming", 0).eta is None
    assert Progress(10, 500, 2.0, math.inf, 5.0, {}, "streaming", 0).eta is None
    assert Progress(0, 500, 0.0, 100.0, 0.5, {}, "streaming", 0).eta is None
    assert Progress(500, 500, 100.0, 100.0, 50.0, {}, "done", 0).eta == 0.0
