"""The real CLI on mutants of the shared samples (issue #24, item 5).

Each G-code sample's first 2000 lines go through ``printability postprocess -o OUT``; each
shared SVG through ``printability analyze`` and, as the nozzle of a square part, through
``--nozzle polygon:FILE``. Every run must end clean (exit 0) or with one paragraph
``printability: error:`` and exit 1: no traceback, no hang. The mutants are seeded (see
``_fuzz.py``; ``python tests/fuzz/_fuzz.py --count 50`` explores more); the default run tries
a few per sample, the ``slow`` one many.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from _fuzz import (
    NOZZLE,
    gcode_jobs,
    head_lines,
    report,
    run_all,
    run_cli,
    square_part,
    svg_jobs,
)

SEED = 24  # the number: a red run names a regression, not a new draw
HANG = 60.0  # seconds after which a run counts as a hang (a normal one takes 1–3 s)


@pytest.fixture(scope="module")
def warm(tmp_path_factory, shared_data):
    """One unmutated run of each command first, one at a time: a kernel cache that is cold
    (a new checkout, an edited kernel) compiles here, not inside a timed mutant."""
    folder = tmp_path_factory.mktemp("fuzz-warm")
    gcode = folder / "head.gcode"
    gcode.write_bytes(head_lines(sorted((shared_data / "gcode").glob("*.gcode"))[0]))
    svg = sorted((shared_data / "svg").glob("*.svg"))[0]
    part = square_part(folder)
    for args in (["postprocess", str(gcode), "-o", str(folder / "out.gcode"), "--nozzle",
                  NOZZLE], ["analyze", str(svg), "--no-progress", "-j", "1"],
                 ["analyze", str(part), "--nozzle", f"polygon:{svg}", "--no-progress", "-j",
                  "1"]):
        outcome = run_cli(args, timeout=900)
        assert outcome.kind == "clean", outcome.stderr
    return folder


def _fuzz(name: str, jobs: list[list[str]], capsys) -> None:
    tally = run_all(jobs, timeout=HANG, workers=min(2, os.cpu_count() or 1))
    text = report(tally, name)
    with capsys.disabled():
        print("\n" + text)
    assert not tally.failures(), text


def _gcode(shared_data: Path) -> list[Path]:
    return sorted((shared_data / "gcode").glob("*.gcode"))


def _svgs(shared_data: Path) -> list[Path]:
    return sorted((shared_data / "svg").glob("*.svg"))


def test_postprocess_on_mutated_gcode(warm, shared_data, tmp_path, capsys):
    _fuzz("gcode postprocess", gcode_jobs(_gcode(shared_data), SEED, 3, tmp_path), capsys)


def test_analyze_and_nozzle_on_mutated_svg(warm, shared_data, tmp_path, capsys):
    jobs = svg_jobs(_svgs(shared_data), SEED, 4, tmp_path, square_part(tmp_path))
    _fuzz("svg analyze / nozzle", jobs, capsys)


@pytest.mark.slow
def test_postprocess_on_many_mutants(warm, shared_data, tmp_path, capsys):
    _fuzz("gcode postprocess (slow)", gcode_jobs(_gcode(shared_data), SEED + 1, 25, tmp_path),
          capsys)


@pytest.mark.slow
def test_analyze_and_nozzle_on_many_mutants(warm, shared_data, tmp_path, capsys):
    jobs = svg_jobs(_svgs(shared_data), SEED + 1, 25, tmp_path, square_part(tmp_path))
    _fuzz("svg analyze / nozzle (slow)", jobs, capsys)
