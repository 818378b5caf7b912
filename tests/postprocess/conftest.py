"""Short real slicer files for the post-processing tests (first layers of the shared samples)
and Cura's script package with our shim in it."""

from __future__ import annotations

import importlib
import shutil
import sys
import textwrap
from pathlib import Path

import pytest
from pp_helpers import first_layers


@pytest.fixture(scope="session")
def prusa_short(shared_data: Path, tmp_path_factory) -> Path:
    """PrusaSlicer 2.7.4, marlin2, relative E, arcs: the first 6 layers."""
    out = tmp_path_factory.mktemp("pp") / "prusa_short.gcode"
    out.write_bytes(first_layers(shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode", 6))
    return out


@pytest.fixture(scope="session")
def benchy_short(shared_data: Path, tmp_path_factory) -> Path:
    """Slic3r PE 1.33 + ArcWelder, reprap, absolute E, no layer comments: first ~4 layers."""
    src = shared_data / "gcode" / "slic3rpe_1.33_arcwelder_benchy.gcode"
    data = src.read_bytes()
    # layers are found from Z: cut before the 5th "G1 Z" layer move
    pos = -1
    for _ in range(5):
        pos = data.find(b"\nG1 Z", pos + 1)
    out = tmp_path_factory.mktemp("pp") / "benchy_short.gcode"
    out.write_bytes(data[: pos + 1])
    return out


ROOT = Path(__file__).resolve().parents[2]


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
