"""``printability demo`` through the real entry point: the whole pipeline on the bundled part."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from printability.app.demo import DEMO_PART


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "printability", "demo", *args],
                          capture_output=True, text=True, timeout=900,
                          env={**os.environ, "MPLBACKEND": "Agg"})


def test_demo_runs_the_pipeline_and_keeps_the_mmc_promise(tmp_path):
    out = tmp_path / "report"
    # A board reset mid-print (disconnect@900): the host reconnects and restores the state;
    # the simulator keeps the nozzle's physical place across the reset, as hardware does.
    r = run("--out", str(out), "--faults", "corrupt~0.01,drop-ok~0.005,duplicate-ok~0.005,"
            "busy~0.01,disconnect@900", "--seed", "2")
    assert r.returncode == 0, r.stderr
    assert "simulator log equals the file: yes" in r.stdout
    assert f"report: {out / 'report.html'}" in r.stdout
    doc = json.loads((out / "report.json").read_text())
    # Ranking: the elliptical nozzle, turned by the rotary axis, loses less than the round one.
    assert [n["nozzle"] for n in doc["ranking"]] == ["ellipse:major=0.8,minor=0.4",
                                                     "circle:d=0.8"]
    assert doc["ranking"][0]["lost_area"] < doc["ranking"][1]["lost_area"]
    # Streamed through the faults, with a reconnect, nothing lost or repeated.
    assert doc["simulator_log_equals_file"] is True
    assert doc["stream"]["completed"] and doc["stream"]["resends"] > 0
    assert doc["stream"]["reconnects"] == 1
    # Target, prediction, deposition per layer: nothing outside the part.
    assert len(doc["layers"]) == 4 and doc["violations"] == 0
    for layer in doc["layers"]:
        assert layer["outside_area"] < 1e-6
        assert 0.8 < layer["covered_target"] <= 1.0
        assert layer["deposited_area"] <= layer["target_area"] + 1e-6
    gcode = (out / "part.gcode").read_text()
    assert " C" in gcode and "G92 C0" in gcode
    html = (out / "report.html").read_text()
    assert 'src="layers.png"' in html and (out / "layers.png").stat().st_size > 1000
    record = json.loads((out / "record.json").read_text())
    assert record["format"] == "printability-simulator-record"
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]


def test_bundled_part_ships_with_the_package():
    assert DEMO_PART.is_file() and DEMO_PART.suffix == ".stl"


@pytest.mark.parametrize("args, message", [
    (["--nozzle", "hexagon:d=1"], "unknown nozzle kind"),
    (["--faults", "melt@3"], "unknown fault kind"),
])
def test_bad_options_are_clear_errors(tmp_path, args, message):
    r = run("--out", str(tmp_path / "o"), *args)
    assert r.returncode == 1 and message in " ".join(r.stderr.split())
    assert "Traceback" not in r.stderr


def test_unwritable_report_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = run("--out", str(blocker / "sub"))
    assert r.returncode == 1 and "cannot create the report folder" in " ".join(r.stderr.split())
