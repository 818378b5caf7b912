"""Shared fixtures: paths to the real data in ../shared/data."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("PRINTABILITY_SHARED_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The ../shared/data folder; tests that need it are skipped loudly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder not found at {SHARED_DATA}")
    return SHARED_DATA


def _hypothesis_profiles() -> None:
    """CI replays the same examples every run (a red CI names a real regression, not a new
    random draw); local runs keep exploring. Select with HYPOTHESIS_PROFILE."""
    from hypothesis import settings

    settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
    settings.register_profile("dev", deadline=None, print_blob=True)
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI")
                                         else "dev"))


_hypothesis_profiles()


@pytest.fixture(autouse=True)
def _no_postprocess_server(monkeypatch):
    """A ``printability serve`` the developer left running must not answer the tests' plug-in
    runs (its code may be older than the tree's): the plug-in runs locally unless a test
    points PRINTABILITY_SERVER at its own server."""
    monkeypatch.setenv("PRINTABILITY_SERVER", "off")


# --- no absurd number in emitted G-code (issue #24) ----------------------------------------

#: A word of a coordinate, extrusion, feed rate or rotary axis whose number is not finite, at
#: least 1e6 in magnitude (the reader's own limit on coordinates) or in Python's exponent
#: notation (``1e+16``, what ``repr`` gives huge floats), outside comments. Words may follow
#: digits (``G1X10Y20``), not letters (``ACCEL=...``).
_ABSURD_WORD = re.compile(
    rb"(?<![A-Za-z_])[XYZEFC][-+]?(?:(?:nan|inf)(?![A-Za-z])|0*[1-9][0-9]{6,}|[0-9.]+e[-+][0-9])",
    re.IGNORECASE)
_COMMENT = re.compile(rb";[^\n]*")


def absurd_gcode_words(data: bytes, limit: int = 3) -> list[str]:
    """Up to ``limit`` lines of ``data`` (G-code) holding an X/Y/Z/E/F/C word whose number is
    nan, inf, at least 1e6 in magnitude or in exponent notation, comments left out."""
    code = _COMMENT.sub(b"", data)
    found = []
    for m in _ABSURD_WORD.finditer(code):
        start = code.rfind(b"\n", 0, m.start()) + 1
        end = code.find(b"\n", m.end())
        line_no = code.count(b"\n", 0, m.start()) + 1
        found.append(f"line {line_no}: {code[start:end if end >= 0 else None][:120]!r}")
        if len(found) >= limit:
            break
    return found


@pytest.fixture(autouse=True)
def _emitted_gcode_is_sane(request):
    """After each test that has a ``tmp_path``, every ``*.gcode`` file printability wrote there
    during the test (it names printability in a comment: ``; printability...``, ``generated
    by printability``) holds no non-finite or out-of-range X/Y/Z/E/F/C word; otherwise the
    test fails at teardown. Inputs a test writes on purpose (mutants, bad numbers) do not
    name printability and are not checked. Cost: a regular-expression pass over the files."""
    if "tmp_path" not in request.fixturenames:
        yield
        return
    folder = request.getfixturevalue("tmp_path")
    started = time.time() - 1.0
    yield
    bad = []
    for path in folder.rglob("*.gcode"):
        try:
            if not path.is_file() or path.stat().st_mtime < started:
                continue
            data = path.read_bytes()
        except OSError:
            continue
        if b"printability" not in data:
            continue
        for line in absurd_gcode_words(data):
            bad.append(f"{path.name}, {line}")
    if bad:
        pytest.fail("emitted G-code holds a non-finite or out-of-range number:\n"
                    + "\n".join(bad), pytrace=False)
