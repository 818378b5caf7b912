"""The plugin in a real OctoPrint server (issue #29, "What must hold").

OctoPrint 1.11 from PyPI, built by ``scripts/build-octoprint`` into build/octoprint-venv with
printability and the plugin, is started on 127.0.0.1 with a temporary base folder and an API key
(see _op_server.py). Files go in through its REST API as its upload button sends them; the
rewritten file, the summary, the report and the settings are read back through the same API.
"""

from __future__ import annotations

import contextlib
import difflib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _cdp import CHROMIUM, Browser
from _op_server import ROOT, needs_octoprint, octoprint_server

from printability.model.nozzle import parse_nozzle

pytestmark = needs_octoprint()

ELLIPSE = "ellipse:major=0.8,minor=0.3"
SETTINGS = {"nozzle": ELLIPSE, "machine": "ttr", "uploads": "auto", "flavor": "auto"}


@pytest.fixture(scope="module")
def octo(tmp_path_factory):
    with octoprint_server(tmp_path_factory.mktemp("octoprint"),
                          plugin_settings=SETTINGS) as server:
        yield server
        assert server.alive(), "OctoPrint died during the tests:\n" + server.tail()
        log = server.log_text()
        assert "Traceback" not in log, log[-4000:]


def _cli(source: Path, out: Path, args: list[str]) -> None:
    r = subprocess.run([sys.executable, "-m", "printability", "postprocess", str(source),
                        "-o", str(out), *args], capture_output=True, text=True, timeout=600,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr


def _set(octo, **values) -> None:
    status, body = octo.post_json("api/settings", {"plugins": {"printability": values}})
    assert status == 200, body


# ------------------------------------------------------------------ upload → rewrite


def test_an_upload_is_rewritten_beside_it_as_the_cli_writes_it(octo, sliced_cube, tmp_path):
    original = sliced_cube.read_bytes()
    status, body = octo.upload("cube.gcode", original)
    assert status == 201, body
    assert body["done"] is True  # the upload request does not wait for the rewrite
    job = octo.wait_job("cube.gcode")
    assert job["state"] == "done", job
    assert job["output"] == "cube.rotary.gcode"
    rewritten = (octo.uploads / "cube.rotary.gcode").read_bytes()
    assert (octo.uploads / "cube.gcode").read_bytes() == original  # the upload is kept as is

    # the bytes printability postprocess writes for the same input and settings
    summary = octo.get("api/plugin/printability?path=cube.rotary.gcode")
    assert summary["cli"] == ["--nozzle", ELLIPSE, "--machine", "ttr"]
    cli = tmp_path / "cli.gcode"
    _cli(sliced_cube, cli, summary["cli"])
    assert rewritten == cli.read_bytes()
    assert b"\nG1 " in rewritten and b" C" in rewritten
    assert summary["rotary_words"] > 0
    assert rewritten.count(b"C") >= summary["rotary_words"]

    # the summary: lost area per layer, what could not be printed, print time before/after
    assert len(summary["layers"]) == 100
    assert all({"z", "lost_area", "dropped_moves", "dropped_length"} <= set(r)
               for r in summary["layers"])
    assert summary["lost_area"] == pytest.approx(sum(r["lost_area"] for r in summary["layers"]))
    assert summary["print_time_out"] >= summary["print_time_in"] > 0
    # the original points at its rewrite; OctoPrint's file API carries both notes
    assert octo.get("api/plugin/printability?path=cube.gcode")["output"] == "cube.rotary.gcode"
    meta = octo.get("api/files/local/cube.gcode")
    assert meta["printability"]["status"] == "done"
    files = {f["name"] for f in octo.get("api/files")["files"]}
    assert {"cube.gcode", "cube.rotary.gcode"} <= files
    status, page, headers = octo.request("GET",
                                         "plugin/printability/summary?path=cube.rotary.gcode")
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert b"not printable" in page and b"print time" in page
    # the notification the UI shows, one paragraph
    (event,) = [e for e in octo.plugin_state()["events"] if e.get("job") == job["id"]]
    assert event["level"] == "success" and "\n" not in event["text"]
    assert "rotary words" in event["text"] and "print time" in event["text"]
    # the rewritten file is not rewritten again
    time.sleep(0.5)
    assert [j["name"] for j in octo.plugin_state()["jobs"]].count("cube.rotary.gcode") == 0


THIN = b"""; a hand-made excerpt: two layers of hair-thin lines no elliptical nozzle can lay
M83
G28
G1 Z0.2 F3000
;LAYER_CHANGE
;Z:0.2
;HEIGHT:0.2
G1 X100 Y100 F6000
;TYPE:External perimeter
;WIDTH:0.1
G1 X110 Y100 E0.02 F1200
G1 X110 Y110 E0.02
G1 X100 Y110 E0.02
G1 X100 Y100 E0.02
;LAYER_CHANGE
;Z:0.4
;HEIGHT:0.2
G1 Z0.4 F3000
G1 X110 Y100 E0.02 F1200
G1 X110 Y110 E0.02
M84
"""


@pytest.mark.parametrize(("name", "content", "words"), [
    ("malformed.gcode", b"G28\nG1 X10 Y10 E1\nG1 Xfoo Y--3 E\nG1 X20 Y20 E2\n",
     "line 3: this move has X without a number"),
    ("binary.gcode", b"G1 X1\x00\x01\x02\xff\xfe" + bytes(range(256)) * 20,
     "line 1: binary data"),
    ("thin.gcode", THIN, "can print none of the part"),
])
def test_a_bad_upload_leaves_octoprint_up_the_file_untouched_and_says_why(octo, name, content,
                                                                          words):
    status, body = octo.upload(name, content)
    assert status == 201, body
    job = octo.wait_job(name)
    assert job["state"] == "failed", job
    assert words in job["error"] and "\n" not in job["error"]
    assert "Traceback" not in job["error"] and str(octo.uploads) not in job["error"]
    assert job["error"].startswith(name)
    assert (octo.uploads / name).read_bytes() == content
    assert not any(p.name.startswith(name.split(".")[0] + ".rotary") for p in
                   octo.uploads.iterdir())
    (event,) = [e for e in octo.plugin_state()["events"] if e.get("job") == job["id"]]
    assert event["level"] == "error" and event["text"] == job["error"]
    assert octo.get("api/files/local/" + name)["printability"]["status"] == "failed"
    assert octo.alive() and octo.get("api/version")["server"].startswith("1.11")


# ------------------------------------------------------------------ settings


def test_settings_are_checked_by_printabilitys_parser(octo, short_gcode):
    try:
        _set(octo, nozzle="ellipse:major=0.8")
        state = octo.plugin_state()
        assert state["settings"]["nozzle"] == ELLIPSE  # refused: the one before stays
        with pytest.raises(Exception) as err:
            parse_nozzle("ellipse:major=0.8")
        (event,) = [e for e in state["events"] if e.get("kind") == "settings"][-1:]
        assert event["message"] == str(err.value) and event["level"] == "error"
        status, check = octo.post_json("api/plugin/printability",
                                       {"command": "check", "nozzle": "blob:x=1",
                                        "machine": "ttr-klipper"})
        assert status == 200 and not check["ok"]
        assert check["errors"]["nozzle"].startswith("unknown nozzle kind 'blob'")
        assert check["values"] == {"machine": "ttr-klipper"}
        status, svg, headers = octo.request("GET", "plugin/printability/nozzle.svg?spec="
                                            "rect:w%3D0.8%2Ch%3D0.3")
        assert status == 200 and headers["Content-Type"].startswith("image/svg+xml")
        assert svg.startswith(b"<svg")

        # rewrite on request: an upload is left alone until asked for
        _set(octo, uploads="request")
        assert octo.plugin_state()["settings"]["uploads"] == "request"
        status, _ = octo.upload("asked.gcode", short_gcode.read_bytes())
        assert status == 201
        time.sleep(1.0)
        assert not any(j["name"] == "asked.gcode" for j in octo.plugin_state()["jobs"])
        status, body = octo.post_json("api/plugin/printability",
                                      {"command": "rewrite", "path": "asked.gcode"})
        assert status == 202, body
        assert octo.wait_job("asked.gcode")["state"] == "done"
        assert (octo.uploads / "asked.rotary.gcode").is_file()
        status, body = octo.post_json("api/plugin/printability",
                                      {"command": "rewrite", "path": "nowhere.gcode"})
        assert status == 404 and "nowhere.gcode" in body["error"]
    finally:
        _set(octo, **SETTINGS)
    assert octo.plugin_state()["settings"] == SETTINGS


def test_the_analysis_report_is_reachable(octo, short_gcode):
    octo.upload("reported.gcode", short_gcode.read_bytes())
    octo.wait_job("reported.gcode")
    status, body = octo.post_json("api/plugin/printability",
                                  {"command": "report", "path": "reported.gcode"})
    assert status == 202, body
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        (job,) = [j for j in octo.plugin_state()["jobs"] if j["id"] == body["job"]]
        if job["state"] in ("done", "failed"):
            break
        time.sleep(0.3)
    assert job["state"] == "done", job
    status, page, headers = octo.request("GET", job["report"])
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert b"ellipse" in page


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install "
                    "chromium; scripts/system-packages.txt lists it)")
def test_settings_page_in_headless_chromium(octo, tmp_path):
    """The settings page renders with the nozzle drawn, refuses an invalid SPEC with the
    parser's message, and the page logs no error (screenshots in tmp_path)."""
    browser = Browser(tmp_path / "profile")
    try:
        browser.navigate(octo.url)
        browser.wait_for("window.OctoPrint && OctoPrint.coreui && OctoPrint.coreui.startedUp",
                         timeout=90, what="OctoPrint's UI to start")
        browser.evaluate("$('#navbar_show_settings').click(); true")
        browser.wait_for("$('#settings_dialog').is(':visible')", what="the settings dialog")
        browser.evaluate("$('#settings_plugin_printability_link a').click(); true")
        browser.wait_for("$('#settings_plugin_printability').is(':visible')",
                         what="printability's settings page")
        img = "document.getElementById('printability-nozzle-preview')"
        browser.wait_for(f"{img}.complete && {img}.naturalWidth > 0", what="the nozzle drawing")
        assert browser.evaluate("$('#printability-nozzle').val()") == ELLIPSE
        facts = browser.evaluate("$('.printability-facts').text()")
        assert facts.startswith("ellipse, 1 orifice") and "turns on the rotary axis" in facts
        assert browser.evaluate("$('#printability-uploads').val()") == "auto"
        flavors = browser.evaluate("$('#printability-flavor option').map(function () "
                                   "{ return this.value; }).get()")
        assert flavors == ["auto", "marlin", "klipper", "reprap", "generic"]
        browser.screenshot(tmp_path / "settings.png")

        browser.evaluate("$('#printability-nozzle').val('ellipse:major=0.8').trigger('change');"
                         " true")
        with pytest.raises(Exception) as err:
            parse_nozzle("ellipse:major=0.8")
        shown = browser.wait_for("$('#printability-nozzle-error').is(':visible') && "
                                 "$('#printability-nozzle-error').text()",
                                 what="the refusal under the nozzle field")
        assert shown == str(err.value)
        assert not browser.evaluate("$('#printability-nozzle-preview').is(':visible')")
        browser.screenshot(tmp_path / "settings-refused.png")
        # saving keeps the nozzle installed before
        browser.evaluate("$('[data-test-id=\"settings-save\"]').click(); true")
        browser.wait_for("!$('#settings_dialog').is(':visible')", what="the dialog to close")
        browser.pump(1.0)
        assert octo.plugin_state()["settings"]["nozzle"] == ELLIPSE
        # the tab
        browser.evaluate("$('a[href=\"#tab_plugin_printability\"]').click(); true")
        browser.wait_for("$('#tab_plugin_printability').is(':visible') && "
                         "$('#printability-axis').text()", what="the tab")
        browser.screenshot(tmp_path / "tab.png")
        browser.pump(0.5)
    finally:
        browser.close()
    assert (tmp_path / "settings.png").stat().st_size > 10_000
    assert browser.errors == [], browser.errors


# ------------------------------------------------------------------ the printer


@contextlib.contextmanager
def _simulator(*args: str):
    """``printability simulate --pty --clock sim``; yields (process, port)."""
    proc = subprocess.Popen([sys.executable, "-m", "printability", "simulate", "--pty",
                             "--clock", "sim", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else port
        yield proc, port
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def _connect(octo, port: str) -> None:
    status, body = octo.post_json("api/connection", {"command": "connect", "port": port,
                                                     "baudrate": 115200})
    assert status == 204, body
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if octo.get("api/connection")["current"]["state"] == "Operational":
            return
        time.sleep(0.2)
    raise AssertionError("OctoPrint did not connect:\n" + octo.tail())


def _disconnect(octo) -> None:
    octo.post_json("api/connection", {"command": "disconnect"})
    deadline = time.monotonic() + 30
    while octo.get("api/connection")["current"]["state"] != "Closed" \
            and time.monotonic() < deadline:
        time.sleep(0.2)


def _axis(octo, timeout: float = 30) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        axis = octo.plugin_state()["axis"]
        if axis["state"] in ("ok", "missing"):
            return axis
        time.sleep(0.2)
    raise AssertionError(f"no axis check in {timeout} s: {octo.plugin_state()['axis']}")


ROTARY = b"G28\nG1 Z0.2 F600\nG1 X10 Y10 C0 F3000\nG1 X20 Y10 C90\nM400\n"


@pytest.mark.parametrize("machine", ["ttr", "xy"])
def test_the_rotary_axis_is_checked_on_connect(octo, machine):
    # a file named like the plugin's output: never rewritten, cancelled on a printer
    # without the axis
    status, _ = octo.upload("turns.rotary.gcode", ROTARY)
    assert status == 201
    with _simulator("--machine", machine, "--quiet") as (_, port):
        _connect(octo, port)
        try:
            axis = _axis(octo)
            if machine == "xy":
                status, body = octo.post_json("api/files/local/turns.rotary.gcode",
                                              {"command": "select", "print": True})
                assert status == 204, body
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline and not any(
                        e["title"] == "printability: turns.rotary.gcode cancelled"
                        for e in octo.plugin_state()["events"]):
                    time.sleep(0.2)
                deadline = time.monotonic() + 30
                while octo.get("api/job")["state"] != "Operational" \
                        and time.monotonic() < deadline:
                    time.sleep(0.2)
                assert octo.get("api/job")["state"] == "Operational"
        finally:
            _disconnect(octo)
    assert not any(j["name"] == "turns.rotary.gcode" for j in octo.plugin_state()["jobs"])
    if machine == "ttr":
        assert axis["state"] == "ok" and axis["letter"] == "C", axis
        return
    assert axis["state"] == "missing", axis
    (cancel,) = [e for e in octo.plugin_state()["events"]
                 if e["title"] == "printability: turns.rotary.gcode cancelled"]
    assert cancel["text"] == axis["message"]
    # the message printability stream gives
    assert axis["message"].startswith(
        "The rotary G-code printability writes for machine ttr drives a rotary axis C but "
        f"the printer on {port} (Marlin")
    assert "reports the axes X, Y, Z; nothing was sent" in axis["message"]
    events = [e for e in octo.plugin_state()["events"] if e.get("kind") == "axis"]
    assert events and events[-1]["text"] == axis["message"]


@pytest.mark.slow
def test_octoprint_prints_the_rewritten_file_on_the_simulator(octo, sliced_cube, tmp_path):
    """OctoPrint streams the rewritten cube (about 14 000 commands) to ``printability simulate
    --pty --clock sim``: the simulator executes the file's commands exactly once and in order
    (beside OctoPrint's own protocol commands), and deposits what the same file deposits when
    the project's reference host streams it in-process. OctoPrint stays connected after the
    print (the simulator's M155 reports on the wall clock feed its watchdog)."""
    import serial

    from simulators import Link, make_config

    sys.path.insert(0, str(ROOT / "tests" / "simulators"))
    from _sim_helpers import MiniHost, file_commands

    if not (octo.uploads / "cube.rotary.gcode").is_file():
        octo.upload("cube.gcode", sliced_cube.read_bytes())
        assert octo.wait_job("cube.gcode")["state"] == "done"
    path = octo.uploads / "cube.rotary.gcode"
    commands = file_commands(path)
    record = tmp_path / "record.json"
    with _simulator("--nozzle", ELLIPSE, "--record", str(record), "--quiet") as (_, port):
        _connect(octo, port)
        try:
            t0 = time.monotonic()
            status, body = octo.post_json("api/files/local/cube.rotary.gcode",
                                          {"command": "select", "print": True})
            assert status == 204, body
            deadline = t0 + 600
            while time.monotonic() < deadline:
                job = octo.get("api/job")
                if job["state"] == "Operational" and job["progress"]["completion"] == 100:
                    break
                time.sleep(0.5)
            else:
                raise AssertionError(f"the print did not end in 600 s: {job}")
            print(f"OctoPrint printed {len(commands)} commands in "
                  f"{time.monotonic() - t0:.1f} s")
            time.sleep(12)  # OctoPrint declared the printer dead 9.2 s after a print ended
            assert octo.get("api/connection")["current"]["state"] == "Operational"
        finally:
            _disconnect(octo)
        time.sleep(0.5)
    doc = json.loads(record.read_text())
    executed = [text for _, text in doc["log"]]
    # OctoPrint's own commands: the handshake, firmware info, the busy protocol interval, SD
    # init, temperature auto-reports, the plugin's M114, M400 after the print
    own = ("M110", "M113", "M114", "M115", "M155", "M21", "M105", "M400")
    i = executed.index(commands[0])
    assert all(t.startswith(own) for t in executed[:i]), executed[:i]
    # the file's commands, each once and in order; between them only OctoPrint's own
    match = difflib.SequenceMatcher(a=commands, b=executed[i:], autojunk=False)
    for op, a0, a1, b0, b1 in match.get_opcodes():
        if op == "equal":
            continue
        assert op == "insert" and all(t.startswith(own) for t in executed[i + b0:i + b1]), \
            (op, commands[a0:a1][:5], executed[i + b0:i + b1][:5])
    assert sum(b.size for b in match.get_matching_blocks()) == len(commands)
    stats = doc["stats"]
    assert stats["unknown_commands"] == 0 and stats["cold_extrusions"] == 0
    assert stats["refused_moves"] == 0 and stats["errors"] == {}

    # the same file through the reference host
    ser = serial.serial_for_url("printsim://", timeout=0, do_not_open=True)
    ser.simulator = Link(make_config(nozzle=ELLIPSE))
    ser.open()
    MiniHost(ser).stream(commands)
    ser.close()
    ser.simulator.firmware.drain()
    ref = ser.simulator.firmware.record()
    assert [lay["z"] for lay in doc["layers"]] == pytest.approx([lay.z for lay in ref.layers])
    assert [lay["deposited_area"] for lay in doc["layers"]] == pytest.approx(
        [lay.area for lay in ref.layers], rel=1e-9)
    assert stats["extruded_mm"] == pytest.approx(ref.stats["extruded_mm"], rel=1e-12)
    assert len(doc["layers"]) == 100
