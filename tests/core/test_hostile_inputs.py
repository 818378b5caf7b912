"""The real CLI on the inputs of issue #24 not covered elsewhere: numbers refused where they
enter (a machine TOML, a nozzle outline, a slice file, a G-code move), special files given as
a machine profile or a nozzle outline, and error text that quotes at most a short excerpt of
what the user gave. Each run ends with exit 1 and one ``printability: error:`` paragraph:
no traceback, no warning, no hang."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from printability.app.cli.main import ERROR_LENGTH, error_paragraph
from printability.errors import FileFormatError

ROOT = Path(__file__).resolve().parents[2]
TTR_TOML = ROOT / "printability" / "data" / "machines" / "ttr.toml"
SQUARE = "POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))"
ELLIPSE = "ellipse:major=0.8,minor=0.3"
GCODE_HEAD = "G28\nG90\nM83\nG1 Z0.2 F600\nG1 X10 Y10 F1200\n"


def cli(*args: str, cwd: Path, timeout: float = 120) -> tuple[int, str, float]:
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "printability", *args], cwd=cwd,
                       capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, "PRINTABILITY_SERVER": "off"})
    return r.returncode, r.stderr, time.monotonic() - t0


def one_paragraph_error(rc: int, err: str) -> str:
    assert rc == 1, err[-2000:]
    assert "Traceback" not in err and "Warning" not in err, err[-2000:]
    assert err.startswith("printability: error: ") and "\n\n" not in err.strip(), err[-2000:]
    return " ".join(err.split())


def _files(tmp: Path) -> None:
    (tmp / "square.wkt").write_text(SQUARE)
    toml = TTR_TOML.read_text()
    assert "\nstep = 2.0" in toml
    (tmp / "tiny_step.toml").write_text(toml.replace("\nstep = 2.0", "\nstep = 1e-9", 1))
    (tmp / "huge.toml").write_text("# " + "x" * (2 << 20) + "\n")
    os.mkfifo(tmp / "fifo.toml")
    (tmp / "nan.txt").write_text("0 0\n0.5 nan\n0.5 0.3\n")
    (tmp / "huge.txt").write_text("0 0\n1e308 0\n0.5 0.3\n")
    (tmp / "wide.txt").write_text("0 0\n2000 0\n0 0.3\n")
    (tmp / "nan.wkt").write_text("POLYGON ((0 0, 0.5 nan, 0.5 0.3, 0 0))")
    (tmp / "huge.wkt").write_text("POLYGON ((0 0, 1e308 0, 0.5 0.3, 0 0))")
    (tmp / "slices_huge.txt").write_text("0.3\n0.7\n3\n0 0\n1e308 0\n0 10\n")
    for name, word in (("xnan", "Xnan"), ("x1e309", "X1e309"), ("x400", "X" + "9" * 400)):
        (tmp / f"{name}.gcode").write_text(GCODE_HEAD + f"G1 {word} Y71.838 E.38291\n")


@pytest.mark.parametrize(("args", "match"), [
    (["analyze", "square.wkt", "-n", ELLIPSE, "-m", "tiny_step.toml"],
     "tiny_step.toml: rotary step must be at least 0.001 degrees"),
    (["analyze", "square.wkt", "-m", "/dev/zero"], "/dev/zero: not a regular file"),
    (["analyze", "square.wkt", "-m", "fifo.toml"], "fifo.toml: not a regular file"),
    (["analyze", "square.wkt", "-m", "huge.toml"], "a machine profile is expected to be at most"),
    (["analyze", "square.wkt", "-n", "polygon:/dev/zero"], "/dev/zero: not a regular file"),
    (["analyze", "square.wkt", "-n", "polygon:nan.txt"], "nan.txt, line 2: expected two numbers"),
    (["analyze", "square.wkt", "-n", "polygon:huge.txt"],
     "huge.txt, line 2: expected finite numbers up to 1e+15; found '1e308 0'"),
    (["analyze", "square.wkt", "-n", "polygon:wide.txt"], "the polygon reaches 2000 mm"),
    (["analyze", "square.wkt", "-n", "polygon:nan.wkt"], "nan.wkt: a coordinate is not finite"),
    (["analyze", "square.wkt", "-n", "polygon:huge.wkt"], "huge.wkt: a coordinate is out of range"),
    (["analyze", "square.wkt", "-n", "polygon:pts=0 0;1e308 0;0 1"],
     "pts= expects finite numbers up to 1e+15; found '1e308 0'"),
    (["analyze", "square.wkt", "-n", "polygon:pts=0 0;1 0;0 1,scale=1e300"],
     "the polygon reaches 1e+300 mm"),
    (["analyze", "slices_huge.txt"],
     "slices_huge.txt, line 5: expected finite coordinates up to 1e+15; found '1e308 0'"),
    (["postprocess", "xnan.gcode", "-o", "out.gcode", "-n", ELLIPSE, "-m", "ttr"],
     "xnan.gcode, line 6: this move has X without a number"),
    (["postprocess", "x1e309.gcode", "-o", "out.gcode", "-n", ELLIPSE, "-m", "ttr"],
     "x1e309.gcode, line 6: this move has a number in exponent notation"),
    (["postprocess", "x400.gcode", "-o", "out.gcode", "-n", ELLIPSE, "-m", "ttr"],
     "x400.gcode, line 6: this move has X out of range"),
])
def test_refused_where_the_number_or_file_enters(tmp_path, args, match):
    _files(tmp_path)
    if args[0] == "analyze":
        args = [*args, "--no-progress", "-j", "1"]
    rc, err, _ = cli(*args, cwd=tmp_path, timeout=60)
    assert match in one_paragraph_error(rc, err)
    assert not (tmp_path / "out.gcode").exists()


SECRET = "root:x:0:0:root:/root:/bin/bash:" + "S" * 300 + "SECRET_TAIL"


@pytest.mark.parametrize(("name", "text", "args"), [
    # a file that is not an outline, given as one: its first line is not repeated whole
    ("passwd", SECRET + "\nbin:x:1:1\n", ["-n", "polygon:passwd"]),
    ("long.txt", "0 0\n" + "1" * 5_000_000 + " SECRET_TAIL\n", ["-n", "polygon:long.txt"]),
    ("long.wkt", "POLYGON ((0 0, " + "x" * 2_000_000 + "SECRET_TAIL))",  # one huge token
     ["-n", "polygon:long.wkt"]),
    ("slices.txt", "0.3\n0.7\n3\n0 0\n" + "7" * 5_000_000 + " SECRET_TAIL\n0 10\n",
     ["slices.txt"]),
    ("long.toml", TTR_TOML.read_text().replace("\nstep = 2.0", '\nstep = "' + "s" * 100_000
                                                + 'SECRET_TAIL"', 1), ["-m", "long.toml"]),
])
def test_errors_quote_a_short_excerpt_of_a_file(tmp_path, name, text, args):
    (tmp_path / name).write_text(text)
    (tmp_path / "square.wkt").write_text(SQUARE)
    files = [a for a in args if a.endswith(".txt")]
    cmd = ["analyze", *(files or ["square.wkt"]), *(a for a in args if a not in files),
           "--no-progress", "-j", "1"]
    rc, err, seconds = cli(*cmd, cwd=tmp_path)
    one_paragraph_error(rc, err)
    assert "SECRET_TAIL" not in err and len(err) < 600, err[:2000]
    assert seconds < 60


@pytest.mark.parametrize("spec", [
    ["-n", "circle:d=" + "9" * 100_000],          # a nozzle spec
    ["-n", "q" * 100_000 + ":d=1"],                # a nozzle kind
    ["-m", "ttr:min=0,max=1,letter=" + "Q" * 100_000],  # a machine spec
    ["--engine", "q" * 100_000],                   # any choice
])
def test_errors_quote_a_short_excerpt_of_an_argument(tmp_path, spec):
    (tmp_path / "square.wkt").write_text(SQUARE)
    rc, err, _ = cli("analyze", "square.wkt", *spec, "--no-progress", "-j", "1", cwd=tmp_path)
    one_paragraph_error(rc, err)
    assert len(err) < 600 and ("expect" in err or "must be" in err), err[:2000]


def test_an_error_paragraph_is_capped_whatever_the_message():
    t0 = time.monotonic()
    text = error_paragraph(FileFormatError("x.gcode", "a" * 10_000_000, line=3))
    assert time.monotonic() - t0 < 2.0
    assert len(text) < ERROR_LENGTH + 200 and text.endswith("characters]")
    assert text.startswith("printability: error: x.gcode, line 3: aaaa")
    words = error_paragraph(ValueError("word " * 2_000_000))
    assert len(words) < ERROR_LENGTH + 200 and "message cut" in words
    short = error_paragraph(ValueError("a  short\nmessage"))
    assert short == "printability: error: a short message"


def test_a_library_warning_is_one_line_of_ours(monkeypatch, capsys, tmp_path):
    """A warning raised inside a library (numpy's RuntimeWarning in trimesh, GEOS's) printed
    its source path and line of code before the one-paragraph error; it is one line now."""
    import warnings

    import printability.sources as sources
    from printability.app.cli.main import run
    from printability.errors import InputError

    def load(*args, **kwargs):
        warnings.warn_explicit("invalid value encountered in cast", RuntimeWarning,
                               "/venv/site-packages/trimesh/grouping.py", 99)
        raise InputError("the part is bad")

    monkeypatch.setattr(sources, "load_layers", load)
    src = tmp_path / "part.wkt"
    src.write_text("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))")
    assert run(["analyze", str(src), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.splitlines() == ["printability: warning: invalid value encountered in cast",
                                "printability: error: the part is bad"], err
    assert warnings.showwarning.__module__ != "printability.app.cli.main"  # put back
