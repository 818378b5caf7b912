"""The entry points run for real on binary G-code: ``printability postprocess`` and the
slicer plug-in (``printability-postprocess``) called by the real PrusaSlicer."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import bg_helpers
import pytest
from bg_helpers import PRUSA_DEFAULT, library_valid

from gcode import parse_gcode
from gcode.bgcode import PRINT_METADATA, PRINTER_METADATA, decode_bgcode
from printability.postprocess import already_processed

ELLIPSE = "ellipse:major=0.8,minor=0.3"
CONFIG = Path(__file__).resolve().parents[1] / "postprocess" / "data" / "prusaslicer_ttr.ini"
STLS = ["CalibrationCube.stl", "ThinWall.stl", "3DBenchy_lowpoly.stl", "HoleTest.stl",
        "Tolerance.stl", "idler_riser_inches.stl"]


def _script(name: str) -> str:
    exe = Path(sys.executable).with_name(name)
    if not exe.exists():
        pytest.skip(f"the console script {name} is not installed next to {sys.executable}")
    return str(exe)


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(list(args), capture_output=True, text=True, timeout=900)


def _kept_blocks(before: bytes, after: bytes) -> None:
    a, b = decode_bgcode(before), decode_bgcode(after)
    skip = (1, PRINT_METADATA, PRINTER_METADATA)
    kept = [before[k.start:k.end] for k in a.blocks if k.type not in skip]
    assert kept and kept == [after[k.start:k.end] for k in b.blocks if k.type not in skip]


def test_the_cli_rewrites_binary_gcode_in_place(sample_binary, tmp_path):
    data = sample_binary("short", *PRUSA_DEFAULT)
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    exe = _script("printability")
    r = _run(exe, "postprocess", "--nozzle", ELLIPSE, "--machine", "ttr", str(f))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "written as binary G-code, heatshrink 12/4, MeatPack with comments" in r.stdout
    new = f.read_bytes()
    assert new[:4] == b"GCDE" and library_valid(new) and already_processed(new)
    g = parse_gcode(new)
    assert (g.words["letter"] == ord("C")).any()
    _kept_blocks(data, new)
    r = _run(exe, "postprocess", "--nozzle", ELLIPSE, "--machine", "ttr", str(f))
    assert r.returncode == 0 and "already post-processed" in r.stdout
    assert f.read_bytes() == new


def test_the_cli_refuses_a_damaged_binary_file_in_one_paragraph(sample_binary, tmp_path):
    data = bytearray(sample_binary("short", *PRUSA_DEFAULT))
    g = decode_bgcode(bytes(data)).gcode_blocks[0]
    data[g.data + 100] ^= 0x40
    f = tmp_path / "part.bgcode"
    f.write_bytes(bytes(data))
    r = _run(_script("printability"), "postprocess", "--nozzle", ELLIPSE, str(f))
    assert r.returncode == 1
    assert r.stderr.startswith("printability: error:") and "\n\n" not in r.stderr.strip()
    assert "Traceback" not in r.stderr
    err = " ".join(r.stderr.split())  # the paragraph is wrapped to the terminal
    assert "part.bgcode: damaged binary G-code" in err  # (the path may wrap at a hyphen)
    assert f"G-code block {g.index + 1} (byte {g.start})" in err
    assert "fails its CRC32 check" in err
    assert f.read_bytes() == bytes(data)


# ----------------------------------------------------------------- PrusaSlicer end to end


@pytest.fixture(scope="module")
def prusa_slicer() -> str:
    exe = shutil.which("prusa-slicer")
    if exe is None:
        pytest.skip("prusa-slicer is not installed (Debian: apt-get install prusa-slicer); "
                    "the end-to-end slicer tests cannot run")
    return exe


def _end_to_end(exe: str, stl: Path, tmp: Path, mode: tuple[int, int]) -> None:
    """PrusaSlicer 2.5 writes text G-code: in its post-processing chain the file is made
    binary (as PrusaSlicer ≥ 2.7 writes it, thumbnails included) and copied aside, then the
    plug-in's console script runs on it, as a 2.7 slicer calls it."""
    from pp_helpers import check_rewritten_part

    before = tmp / "before.bgcode"
    out = tmp / "ttr.gcode"
    plugin = f"{_script('printability-postprocess')} --nozzle {ELLIPSE} --machine ttr"
    make_binary = f"{sys.executable} {bg_helpers.__file__} \"$0\" {mode[0]} {mode[1]}"
    post = f"sh -c '{make_binary} && cp \"$0\" {before} && exec {plugin} \"$0\"'"
    r = _run(exe, "--export-gcode", "--load", str(CONFIG), "--center", "110,110", "-o", str(out),
             "--post-process", post, str(stl))
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    old, new = before.read_bytes(), out.read_bytes()
    assert old[:4] == new[:4] == b"GCDE" and library_valid(new)
    assert already_processed(new) and not already_processed(old)
    _kept_blocks(old, new)
    d0, d1 = decode_bgcode(old), decode_bgcode(new)
    assert {(b.compression, b.encoding) for b in d1.gcode_blocks} == {mode}
    g0, g1 = parse_gcode(old), parse_gcode(new)  # the reader decodes them
    # untouched lines decode as they were, rotary words, deposition inside G
    check_rewritten_part(d0.gcode, d1.gcode, g0, g1, ELLIPSE)


def test_prusaslicer_hands_binary_gcode_to_the_plugin(prusa_slicer, shared_data, tmp_path):
    _end_to_end(prusa_slicer, shared_data / "stl" / "CalibrationCube.stl", tmp_path,
                PRUSA_DEFAULT)


@pytest.mark.slow
@pytest.mark.parametrize("mode", [(0, 0), (1, 1), (2, 0), (3, 2)], ids=str)
@pytest.mark.parametrize("name", STLS)
def test_every_stl_goes_through_the_plugin_as_binary(prusa_slicer, shared_data, tmp_path, name,
                                                     mode):
    _end_to_end(prusa_slicer, shared_data / "stl" / name, tmp_path, mode)
