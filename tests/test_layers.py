"""Layers that import one way (issue #25): the import-linter contracts in pyproject.toml hold.

printability.base is the leaf; gcode uses only printability.base of printability; machine_io
uses gcode and printability.base; simulators use those and the model (printability.model:
geometry, layers, machine, nozzle, shapes); only the applications (printability.app: the CLI,
the demo) import machine_io and simulators.
``lint-imports`` reads the contracts from pyproject.toml.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def _lint_imports() -> str:
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    if not Path(exe).exists():
        pytest.skip("import-linter is not installed (it comes with the 'test' extra)")
    return exe


def _contracts() -> list[dict]:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["tool"]["importlinter"]["contracts"]


def _children() -> set[str]:
    """The modules and packages directly under printability."""
    return {
        f"printability.{p.stem if p.is_file() else p.name}"
        for p in (ROOT / "printability").iterdir()
        if (p.suffix == ".py" and p.stem != "__init__")
        or (p.is_dir() and (p / "__init__.py").exists())
    }


def test_the_import_contracts_hold():
    p = subprocess.run([_lint_imports(), "--no-cache", "--no-logo"], capture_output=True,
                       text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "0 broken" in p.stdout


def test_the_forbidden_lists_name_every_printability_module_but_base():
    """A module added to printability is forbidden to the lower layers without a config edit
    (the contracts list modules because a forbidden contract cannot say 'all but base')."""
    children = _children() - {"printability.base"}
    by_id = {c["id"]: c for c in _contracts()}
    for cid in ("base-is-a-leaf", "gcode-uses-only-base", "machine-io-uses-gcode-and-base"):
        listed = {m for m in by_id[cid]["forbidden_modules"] if m.startswith("printability.")}
        missing = children - listed
        assert not missing, f"{cid}: add {sorted(missing)} to forbidden_modules"
        assert "printability.base" not in listed


MODEL = {"printability.model", "printability.errors", "printability.options",
         "printability.settings", "printability.sources"}
APPLICATIONS = {"printability.__main__", "printability.app"}


def test_simulators_and_the_host_contracts_cover_every_module():
    """simulators may use the model only; everything but the applications is kept from
    machine_io and simulators, a new module included."""
    children = _children()
    by_id = {c["id"]: c for c in _contracts()}
    sim = set(by_id["simulators-use-the-model"]["forbidden_modules"])
    missing = children - sim - MODEL - {"printability.base"}
    assert not missing, f"simulators-use-the-model: add {sorted(missing)} to forbidden_modules"
    apps = by_id["only-applications-drive-machines"]
    assert set(apps["forbidden_modules"]) == {"machine_io", "simulators"}
    missing = children - set(apps["source_modules"]) - APPLICATIONS
    assert not missing, f"only-applications-drive-machines: add {sorted(missing)} to " \
        "source_modules"


def test_a_broken_contract_fails(tmp_path):
    """The linter sees the imports: forbidding gcode what it does import breaks the check."""
    cfg = tmp_path / "contracts.toml"
    cfg.write_text(
        '[tool.importlinter]\nroot_packages = ["printability", "gcode"]\n\n'
        '[[tool.importlinter.contracts]]\nname = "probe"\ntype = "forbidden"\n'
        'source_modules = ["gcode"]\nforbidden_modules = ["printability.base"]\n',
        encoding="utf-8")
    p = subprocess.run([_lint_imports(), "--no-cache", "--no-logo", str(cfg)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "BROKEN" in p.stdout
