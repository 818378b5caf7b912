"""The slicer integrations: the PrusaSlicer-family entry point and the Cura shim."""

from __future__ import annotations

import importlib
import json
import shutil
import sys
import textwrap
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


@pytest.fixture()
def cura_scripts(tmp_path, monkeypatch):
    """Cura's package layout: PostProcessingPlugin/Script.py + scripts/<our shim>."""
    pkg = tmp_path / "PostProcessingPlugin"
    (pkg / "scripts").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "scripts" / "__init__.py").write_text("")
    # Cura's Script base class as far as the shim uses it: settings from the JSON defaults
    (pkg / "Script.py").write_text(textwrap.dedent('''
        import json
        class Script:
            def __init__(self):
                doc = json.loads(self.getSettingDataString())
                self._values = {k: v["default_value"] for k, v in doc["settings"].items()}
            def getSettingValueByKey(self, key):
                return self._values[key]
    '''))
    for name in ("PrintabilityRotary.py", "printability_rotary.json"):
        shutil.copy(ROOT / "plugin" / "cura" / name, pkg / "scripts" / name)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("PostProcessingPlugin.scripts.PrintabilityRotary")
    yield mod
    for key in [k for k in sys.modules if k.startswith("PostProcessingPlugin")]:
        del sys.modules[key]


def test_cura_settings_json_is_valid():
    doc = json.loads((ROOT / "plugin" / "cura" / "printability_rotary.json").read_text())
    assert doc["key"] == "PrintabilityRotary" and doc["version"] == 2
    assert {"nozzle", "machine", "extra", "executable", "timeout"} <= set(doc["settings"])


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
