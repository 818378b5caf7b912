"""Fixtures of the OctoPrint plugin's tests: its OctoPrint-free core loaded in the project's
venv, a part sliced by the real PrusaSlicer, and the real OctoPrint server (see
_op_server.py) that ``scripts/build-octoprint`` installs into build/octoprint-venv."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from _op_server import ROOT, octoprint_available

CORE = ROOT / "plugin" / "octoprint" / "octoprint_printability" / "core.py"
SLICER_CONFIG = ROOT / "tests" / "postprocess" / "data" / "prusaslicer_ttr.ini"
ELLIPSE = "ellipse:major=0.8,minor=0.3"

if not octoprint_available() and os.environ.get("CI"):
    # CI builds OctoPrint in scripts/test: a missing build there is a broken pipeline, not a skip
    raise RuntimeError("CI without an OctoPrint build: scripts/build-octoprint did not run")


@pytest.fixture(scope="session")
def core() -> ModuleType:
    """``octoprint_printability.core``, loaded from its file: the package's ``__init__``
    imports OctoPrint, which the project's venv does not have (and must not: OctoPrint pins
    Flask, Click... of its own), while the core imports only printability."""
    name = "octoprint_printability_core"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, CORE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def sliced_cube(shared_data: Path, tmp_path_factory) -> Path:
    """The shared CalibrationCube.stl sliced by the real PrusaSlicer (Debian's prusa-slicer,
    the configuration of tests/postprocess): 100 layers, 11 656 lines."""
    exe = shutil.which("prusa-slicer")
    if exe is None:
        pytest.skip("prusa-slicer is not installed (Debian: apt-get install prusa-slicer; "
                    "scripts/system-packages.txt lists it)")
    out = tmp_path_factory.mktemp("sliced") / "CalibrationCube.gcode"
    stl = shared_data / "stl" / "CalibrationCube.stl"
    r = subprocess.run([exe, "--export-gcode", "--load", str(SLICER_CONFIG), "--center",
                        "110,110", "-o", str(out), str(stl)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    return out


@pytest.fixture(scope="session")
def short_gcode(shared_data: Path, tmp_path_factory) -> Path:
    """The first 4 layers of the shared PrusaSlicer 2.7.4 sample (marlin2, relative E, arcs)."""
    data = (shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode").read_bytes()
    pos = -1
    for _ in range(5):
        pos = data.find(b";LAYER_CHANGE", pos + 1)
    out = tmp_path_factory.mktemp("short") / "screw_short.gcode"
    out.write_bytes(data[:pos])
    return out
