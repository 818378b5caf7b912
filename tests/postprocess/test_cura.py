"""End to end with Cura's own engine: Debian's CuraEngine 4.13 slices the shared STL files with
Cura's printer definitions (a Creality Ender-3, Marlin), and our Cura script gets the G-code as
Cura's frontend hands it to post-processing scripts: a list of chunks.

Cura 4.13's frontend builds that list from the engine's messages (CuraEngineBackend): the
header ("GCodePrefix": ;FLAVOR, ;TIME, ... up to the blank line) first, then one chunk per
flush of the engine's output: the start code up to ;LAYER:0, one chunk per layer from its
;LAYER: line to its ;TIME_ELAPSED: line, and the end code. The engine run from the command
line writes the same text to a file; ``cura_chunks`` cuts it at those places.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from pp_helpers import check_rewritten_part

from gcode import parse_gcode
from printability.postprocess import already_processed

ROOT = Path(__file__).resolve().parents[2]
DEFINITIONS = ROOT / "build" / "cura"
PRINTER = "creality_ender3"
ELLIPSE = "ellipse:major=0.8,minor=0.3"
STLS = ["CalibrationCube.stl", "ThinWall.stl", "3DBenchy_lowpoly.stl", "HoleTest.stl",
        "Tolerance.stl", "idler_riser_inches.stl"]


@pytest.fixture(scope="module")
def cura_engine() -> str:
    exe = shutil.which("CuraEngine")
    if exe is None:
        pytest.skip("CuraEngine is not installed (Debian: apt-get install cura-engine); the "
                    "Cura end-to-end tests cannot run")
    if not (DEFINITIONS / "definitions" / f"{PRINTER}.def.json").is_file():
        pytest.skip("Cura's printer definitions are missing: run scripts/fetch-cura-definitions "
                    "(scripts/test does)")
    return exe


def _defaults(printer: str) -> dict:
    """The printer's settings' default values along its 'inherits' chain (the child's win)."""
    doc = json.loads((DEFINITIONS / "definitions" / f"{printer}.def.json").read_text())
    values = _defaults(doc["inherits"]) if "inherits" in doc else {}
    for key, setting in doc.get("overrides", {}).items():
        if "default_value" in setting:
            values[key] = setting["default_value"]
    return values


def _start_end_code(printer: str) -> list[str]:
    """The start and end G-code with ``{setting}`` filled in, as Cura's frontend sends them
    (the engine alone leaves the braces: the Ender-3's end code has ``Y{machine_depth}``)."""
    values = _defaults(printer)
    args = []
    for key in ("machine_start_gcode", "machine_end_gcode"):
        code = re.sub(r"\{(\w+)\}", lambda m: str(values[m.group(1)]), values.get(key, ""))
        args += ["-s", f"{key}={code}"]
    return args


def cura_slice(exe: str, stl: Path, out: Path) -> str:
    """Slice ``stl`` as Cura's 'Standard quality' would on an Ender-3 (0.2 mm layers)."""
    env = dict(os.environ, CURA_ENGINE_SEARCH_PATH=os.pathsep.join(
        [str(DEFINITIONS / "definitions"), str(DEFINITIONS / "extruders")]))
    cmd = [exe, "slice", "-j", str(DEFINITIONS / "definitions" / f"{PRINTER}.def.json"),
           "-s", "layer_height=0.2", "-s", "layer_height_0=0.2", *_start_end_code(PRINTER),
           "-e0", "-l", str(stl), "-o", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return out.read_text(encoding="utf-8")


def cura_chunks(text: str) -> list[str]:
    """The chunks Cura 4.13's frontend would hand a script for this engine output."""
    lines = text.splitlines(keepends=True)
    cuts = [next(i for i, ln in enumerate(lines) if ln.strip() == "") + 1]  # end of the header
    last_elapsed = 0
    for i, ln in enumerate(lines):
        if ln.startswith(";LAYER:"):
            cuts.append(i)
        elif ln.startswith(";TIME_ELAPSED:"):
            last_elapsed = i
    cuts.append(last_elapsed + 1)  # the end code
    bounds = [0, *cuts, len(lines)]
    return ["".join(lines[a:b]) for a, b in itertools.pairwise(bounds)]


def _run_script(cura_scripts, chunks: list[str]) -> list[str]:
    script = cura_scripts.PrintabilityRotary()
    script._values["executable"] = str(Path(sys.executable).with_name("printability"))
    return script.execute(list(chunks))


def _end_to_end(exe: str, cura_scripts, stl: Path, tmp: Path) -> None:
    text = cura_slice(exe, stl, tmp / "cura.gcode")
    chunks = cura_chunks(text)
    assert "".join(chunks) == text and chunks[1].startswith(";Generated with Cura")
    out = _run_script(cura_scripts, chunks)

    # the script's chunks are what the command line makes of the joined file
    cli = tmp / "cli.gcode"
    r = subprocess.run([str(Path(sys.executable).with_name("printability")), "postprocess",
                        str(tmp / "cura.gcode"), "--nozzle", ELLIPSE, "--machine", "ttr",
                        "-o", str(cli)], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr[-2000:]
    new = "".join(out)
    assert new == cli.read_text(encoding="utf-8")
    # ... cut where Cura's were: as many, each layer's from its own ;LAYER: line
    assert len(out) == len(chunks)
    for a, b in zip(chunks[1:], out[1:], strict=True):
        assert b.splitlines()[0] == a.splitlines()[0]
    old_b, new_b = text.encode(), new.encode()
    assert already_processed(new_b) and not already_processed(old_b)
    check_rewritten_part(old_b, new_b, parse_gcode(old_b), parse_gcode(new_b), ELLIPSE)


def test_cura_engine_and_the_script_calibration_cube(cura_engine, cura_scripts, shared_data,
                                                    tmp_path):
    _end_to_end(cura_engine, cura_scripts, shared_data / "stl" / "CalibrationCube.stl", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", STLS[1:])
def test_cura_engine_and_the_script_on_every_stl(cura_engine, cura_scripts, shared_data,
                                                tmp_path, name):
    _end_to_end(cura_engine, cura_scripts, shared_data / "stl" / name, tmp_path)


def test_a_failing_script_leaves_curas_chunks(cura_engine, cura_scripts, shared_data, tmp_path,
                                              capsys):
    """A nozzle that prints none of the part: Cura keeps its own G-code and shows why."""
    chunks = cura_chunks(cura_slice(cura_engine, shared_data / "stl" / "ThinWall.stl",
                                    tmp_path / "cura.gcode"))
    script = cura_scripts.PrintabilityRotary()
    script._values["executable"] = str(Path(sys.executable).with_name("printability"))
    script._values["nozzle"] = "circle:d=30"
    assert script.execute(list(chunks)) == chunks
    assert "none of the part" in capsys.readouterr().out


def test_split_like_keeps_chunk_boundaries(cura_scripts):
    split_like = cura_scripts.split_like
    chunks = [";FLAVOR:Marlin\n\n", "G28\n", "", ";LAYER:0\nG1 X1 E1\n", ";LAYER:1\nG1 X2 E2\n"]
    text = (";FLAVOR:Marlin\n; printability\n\nG28\n;LAYER:0\nG1 C5\nG1 X1 E1 C5\n"
            ";LAYER:1\nG1 X2 E2\n")
    assert split_like(text, chunks) == [";FLAVOR:Marlin\n; printability\n\n", "G28\n", "",
                                        ";LAYER:0\nG1 C5\nG1 X1 E1 C5\n", ";LAYER:1\nG1 X2 E2\n"]
    # a boundary that is no longer there: cut at the layers
    assert split_like(text, [";FLAVOR:Marlin\n\n", "G1 X9\n"]) == [
        ";FLAVOR:Marlin\n; printability\n\nG28\n", ";LAYER:0\nG1 C5\nG1 X1 E1 C5\n",
        ";LAYER:1\nG1 X2 E2\n"]
    assert split_like(text, [text]) == [text]
