"""A folder named ``printability`` in the working directory (issue #24): the worker processes
of a multi-layer ``analyze -j 2`` must import the installed package, not that folder (the
fork server is a ``python -c`` child, whose ``sys.path`` starts with the working
directory unless ``PYTHONSAFEPATH`` is set)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CLI = Path(sys.executable).with_name("printability")  # the console script: no cwd on sys.path
COMB = ROOT / "printability" / "data" / "demo" / "comb.stl"


@pytest.mark.skipif(not CLI.exists(), reason="the printability console script is not installed")
def test_a_printability_folder_in_the_working_directory_is_not_imported(tmp_path):
    fake = tmp_path / "printability"
    fake.mkdir()
    (fake / "__init__.py").write_text(
        'raise RuntimeError("the printability folder of the working directory was imported")\n')
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONSAFEPATH", "PYTHONPATH")}
    r = subprocess.run([str(CLI), "analyze", str(COMB), "--layer-height", "0.5", "-j", "2",
                        "--no-progress"], cwd=tmp_path, env={**env, "PRINTABILITY_SERVER": "off"},
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr and "working directory was imported" not in r.stderr
    assert "Σ over 2 layers" in " ".join(r.stdout.split())  # several layers, so workers ran
