"""The slicer integrations: the PrusaSlicer-family entry point and the Cura shim."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from plugin.prusaslicer import build_argv, main
from printability.postprocess import already_processed

ROOT = Path(__file__).resolve().parents[2]
ELLIPSE = "ellipse:major=0.8,minor=0.3"


@pytest.mark.parametrize(("argv", "env", "expected"), [
    (["--nozzle", ELLIPSE, "/tmp/a.gcode"], {},
     ["postprocess", "--nozzle", ELLIPSE, "/tmp/a.gcode"]),
    (["/tmp/a.gcode"], {"PRINTABILITY_POSTPROCESS_ARGS": f"--nozzle {ELLIPSE} --unwind"},
     ["postprocess", "--nozzle", ELLIPSE, "--unwind", "/tmp/a.gcode"]),
    ([], {}, ["postprocess", "--help"]),
])
def test_build_argv(argv, env, expected):
    assert build_argv(argv, env) == expected


def test_prusaslicer_entry_point_in_place(prusa_short, tmp_path, monkeypatch):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    monkeypatch.setenv("SLIC3R_NOZZLE_DIAMETER", "0.4")
    assert main(["--nozzle", ELLIPSE, str(path)]) == 0
    assert already_processed(path.read_bytes())
    missing = tmp_path / "missing.gcode"
    assert main(["--nozzle", ELLIPSE, str(missing)]) == 1


def test_a_slicer_passing_no_file_is_told_why(tmp_path, capsys):
    """OrcaSlicer/Bambu Studio cut the field at ';' and pass temporary paths: a missing file is
    explained as the slicer's call, in one paragraph, without starting the work."""
    path = tmp_path / ".1234.0.gcode.pp"
    assert main(["--nozzle", ELLIPSE, str(path)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert err.startswith("printability: error: the slicer asked to post-process")
    assert str(path) in err and "last argument" in err and "';'" in err
    assert "Traceback" not in err


# Uranium 4.13 (Cura's settings library), UM/Settings/SettingDefinition.py: the properties a
# setting may have, those it must have, the setting types registered by Uranium and Cura, and
# the properties that are Python expressions (strings) rather than values.
_URANIUM_PROPERTIES = {
    "label", "type", "icon", "unit", "description", "warning_description", "error_description",
    "default_value", "value", "enabled", "minimum_value", "maximum_value",
    "minimum_value_warning", "maximum_value_warning", "options", "comments", "allow_empty",
    "is_uuid", "regex_blacklist_pattern", "warning_value", "error_value",
    # added by Cura (cura/CuraApplication.py), and the nesting key
    "resolve", "settable_per_mesh", "settable_per_extruder", "settable_per_meshgroup",
    "settable_globally", "limit_to_extruder", "children"}
_URANIUM_REQUIRED = {"label", "type", "description"}
_URANIUM_TYPES = {"int": int, "float": (int, float), "str": str, "bool": bool, "enum": str,
                  "[int]": str, "polygon": list, "polygons": list, "extruder": str,
                  "optional_extruder": str, "category": str}
_URANIUM_FUNCTIONS = {"value", "enabled", "minimum_value", "maximum_value",
                      "minimum_value_warning", "maximum_value_warning", "allow_empty", "is_uuid",
                      "warning_value", "error_value", "resolve", "limit_to_extruder"}


def test_cura_settings_json_is_valid():
    """The script's settings as Cura's PostProcessingPlugin loads them (a definition container
    of version 2 whose settings Uranium's SettingDefinition accepts)."""
    doc = json.loads((ROOT / "plugin" / "cura" / "printability_rotary.json").read_text())
    assert doc["key"] == "PrintabilityRotary" and doc["version"] == 2
    assert isinstance(doc["name"], str) and isinstance(doc["metadata"], dict)
    assert {"nozzle", "machine", "extra", "executable", "timeout"} <= set(doc["settings"])
    for key, setting in doc["settings"].items():
        assert key.isidentifier(), key
        assert _URANIUM_REQUIRED <= set(setting) <= _URANIUM_PROPERTIES, key
        assert setting["type"] in _URANIUM_TYPES, key
        assert isinstance(setting["default_value"], _URANIUM_TYPES[setting["type"]]), key
        for prop in _URANIUM_FUNCTIONS & set(setting):
            assert isinstance(setting[prop], str), (key, prop)
            compile(setting[prop], key, "eval")


def test_cura_shim_runs_the_cli_on_cura_gcode(cura_scripts, shared_data):
    text = (shared_data / "gcode" / "cura_5.9.1_marlin.gcode").read_text(encoding="utf-8")
    # Cura's chunks: the part before the first layer, then one per ;LAYER:
    chunks = cura_scripts.split_layers(text)[:4]
    script = cura_scripts.PrintabilityRotary()
    script._values["executable"] = str(Path(sys.executable).with_name("printability"))
    out = script.execute(chunks)
    joined = "".join(out)
    assert already_processed(joined.encode())
    assert len(out) == len(chunks)
    assert any(" C" in ln.split(";")[0] for ln in joined.splitlines())


def test_cura_shim_leaves_gcode_on_failure(cura_scripts, capsys):
    script = cura_scripts.PrintabilityRotary()
    script._values["nozzle"] = "blob:d=1"
    script._values["executable"] = str(Path(sys.executable).with_name("printability"))
    data = [";FLAVOR:Marlin\nG28\n", ";LAYER:0\nG1 X1 Y1 Z0.2\nG1 X2 Y1 E0.1\n"]
    assert script.execute(data) == data
    assert "unknown nozzle kind" in capsys.readouterr().out
