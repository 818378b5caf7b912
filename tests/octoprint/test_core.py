"""The OctoPrint plugin's core (plugin/octoprint/octoprint_printability/core.py), without
OctoPrint: settings checked by printability's own parsers and registries, a rewrite that writes
the bytes ``printability postprocess`` writes, its summary, the nozzle's drawing and the
rotary-axis check on connect."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from printability.errors import InputError, NozzleTooLargeError, PrintabilityError
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.options import FLAVORS
from printability.postprocess import PostprocessOptions, postprocess_file

ELLIPSE = "ellipse:major=0.8,minor=0.3"


# ------------------------------------------------------------------ settings


@pytest.mark.parametrize("spec", ["ellipse:major=0.8", "blob:x=1", "circle:d=-1",
                                  "rect:w=0.8,h=0.3,angle=x", "polygon:pts=0 0;1 0"])
def test_a_refused_nozzle_says_what_the_parser_says(core, spec):
    with pytest.raises(PrintabilityError) as theirs:
        parse_nozzle(spec)
    with pytest.raises(PrintabilityError) as ours:
        core.check_setting("nozzle", spec)
    assert str(ours.value) == str(theirs.value)
    accepted, refused = core.check_settings({"nozzle": spec, "uploads": "auto"})
    assert refused == {"nozzle": str(theirs.value)} and accepted == {"uploads": "auto"}


def test_accepted_settings_are_stored_as_the_parsers_read_them(core):
    accepted, refused = core.check_settings({
        "nozzle": f"  {ELLIPSE} ", "machine": "ttr:min=-90,max=90", "uploads": "REQUEST",
        "flavor": "Klipper", "colour": "red"})
    assert refused == {}
    assert accepted == {"nozzle": ELLIPSE, "machine": "ttr:min=-90,max=90",
                        "uploads": "request", "flavor": "klipper"}
    assert core.check_setting("nozzle", "") == ""  # not set yet: nothing is rewritten
    assert core.check_setting("flavor", "auto") == core.FLAVOR_AUTO


@pytest.mark.parametrize(("key", "value", "words"), [
    ("machine", "zz", "unknown machine 'zz'; expected one of: xy, ttr"),
    ("uploads", "sometimes", "unknown upload mode 'sometimes'; expected one of: auto, "
                             "request, never"),
    ("flavor", "repetier", "unknown G-code flavor 'repetier'; expected one of: marlin"),
])
def test_registry_messages(core, key, value, words):
    _, refused = core.check_settings({key: value})
    assert refused[key].startswith(words)


def test_choices_come_from_the_registries(core):
    values = [c["value"] for c in core.flavor_choices()]
    assert values == ["auto", *FLAVORS]
    assert {"ttr", "xy", "ttr-klipper"} <= set(core.machine_choices())
    for spec in core.machine_choices():
        parse_machine(spec)


def test_options_and_cli_arguments(core):
    s = {"nozzle": ELLIPSE, "machine": "ttr", "uploads": "auto", "flavor": "auto"}
    opts = core.options_for(s)
    assert opts == PostprocessOptions(nozzle=ELLIPSE, machine="ttr")
    assert core.cli_arguments(s) == ["--nozzle", ELLIPSE, "--machine", "ttr"]
    k = core.options_for({**s, "flavor": "klipper"})
    assert k.machine.flavor == "klipper" and k.machine.rotary_letter == "C"
    assert core.cli_arguments({**s, "flavor": "klipper"}) is None
    assert core.rotary_letter(s) == "C" and core.rotary_letter({"machine": "xy"}) is None


def test_machine_file_from_the_data_folder(core, tmp_path):
    from printability.model.machine import builtin_profiles

    (tmp_path / "mine.toml").write_bytes(builtin_profiles()["ttr-klipper"].read_bytes())
    assert core.check_setting("machine", " mine.toml", base_dir=tmp_path) == "mine.toml"
    assert core.check_setting("machine", "ttr-klipper") == "ttr-klipper"
    assert core.rotary_letter({"machine": "mine.toml"}, base_dir=tmp_path) == "C"
    with pytest.raises(PrintabilityError):
        core.check_setting("machine", "missing.toml", base_dir=tmp_path)


# ------------------------------------------------------------------ names


@pytest.mark.parametrize(("name", "out"), [("part.gcode", "part.rotary.gcode"),
                                           ("a.b.gco", "a.b.rotary.gco"), ("x", "x.rotary"),
                                           (".gcode", ".gcode.rotary")])
def test_output_names(core, name, out):
    assert core.output_name(name) == out
    assert core.is_rotary_output(out)
    assert not core.is_rotary_output(name)


# ------------------------------------------------------------------ the rewrite


def test_rewrite_writes_what_the_cli_writes(core, short_gcode, tmp_path):
    settings = {"nozzle": ELLIPSE, "machine": "ttr", "uploads": "auto", "flavor": "auto"}
    before = short_gcode.read_bytes()
    ours = tmp_path / "ours.gcode"
    res = core.rewrite_file(short_gcode, ours, settings)
    assert short_gcode.read_bytes() == before  # the upload is never touched
    theirs = tmp_path / "theirs.gcode"
    r = subprocess.run([sys.executable, "-m", "printability", "postprocess", str(short_gcode),
                        "-o", str(theirs), *core.cli_arguments(settings)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert ours.read_bytes() == theirs.read_bytes()
    assert res.rotary_words > 0 and b" C" in ours.read_bytes()

    summary = core.summary_of(res, source="screw.gcode", output="screw.rotary.gcode",
                              settings=settings)
    json.dumps(summary, allow_nan=False)  # served as JSON by the API
    assert summary["rotary_words"] == res.rotary_words
    assert len(summary["layers"]) == len(res.layers) > 0
    assert summary["lost_area"] == pytest.approx(sum(r.dropped_area for r in res.layers))
    assert summary["target_area"] > summary["lost_area"] >= 0
    assert summary["print_time_out"] >= summary["print_time_in"] > 0
    assert summary["cli"] == ["--nozzle", ELLIPSE, "--machine", "ttr"]
    page = core.summary_html({**summary, "output": "<b>x</b>.gcode"})
    assert "&lt;b&gt;x&lt;/b&gt;.gcode" in page and "<b>x</b>" not in page
    assert "print time" in page and "printability postprocess FILE -o OUT" in page

    # a file printability already rewrote is left as it is, nothing new written
    again = tmp_path / "again.gcode"
    res2 = core.rewrite_file(ours, again, settings)
    assert res2.already_processed and not again.exists()


def test_rewrite_with_a_flavor_set_on_the_machine(core, short_gcode, tmp_path):
    out = tmp_path / "k.gcode"
    core.rewrite_file(short_gcode, out, {"nozzle": ELLIPSE, "machine": "ttr",
                                         "flavor": "klipper"})
    expected = tmp_path / "e.gcode"
    postprocess_file(short_gcode, options=core.options_for(
        {"nozzle": ELLIPSE, "machine": "ttr", "flavor": "klipper"}), output=expected, env={})
    assert out.read_bytes() == expected.read_bytes()
    assert b"MANUAL_STEPPER" in out.read_bytes().upper()


def test_a_file_the_planner_cannot_print_is_refused_in_one_paragraph(core, short_gcode,
                                                                     tmp_path):
    before = short_gcode.read_bytes()
    out = tmp_path / "none.gcode"
    with pytest.raises(NozzleTooLargeError) as err:
        core.rewrite_file(short_gcode, out, {"nozzle": "circle:d=30", "machine": "ttr"})
    assert not out.exists() and short_gcode.read_bytes() == before
    text = core.one_paragraph(err.value, name="screw.gcode", disk_path=short_gcode)
    assert "\n" not in text and str(short_gcode) not in text
    assert text.startswith("screw.gcode: nozzle circle:d=30") and "unchanged" in text


def test_one_paragraph_for_any_failure(core):
    text = core.one_paragraph(InputError("bad.gcode, line 2: this move has X without a\n"
                                         "number"), name="bad.gcode")
    assert text == ("bad.gcode, line 2: this move has X without a number. bad.gcode is "
                    "unchanged.")
    text = core.one_paragraph(KeyError("layers"), name="x.gcode")
    assert "internal error (KeyError: 'layers')" in text and "octoprint.log" in text
    assert "Traceback" not in text and text.endswith("x.gcode is unchanged.")


def test_report(core, short_gcode, tmp_path):
    index = core.write_report(short_gcode, tmp_path / "report",
                              {"nozzle": ELLIPSE, "machine": "ttr"}, layers=2)
    assert index.name == "index.html" and index.stat().st_size > 1000
    assert "ellipse" in index.read_text(encoding="utf-8")


# ------------------------------------------------------------------ the drawing


@pytest.mark.parametrize("spec", [ELLIPSE, "rect:w=0.8,h=0.3,x=1,y=0",
                                  "circle:d=0.4,x=-1+circle:d=0.4,x=1",
                                  "polygon:pts=0 0;1 0;1 0.3"])
def test_nozzle_drawing_is_svg(core, spec):
    svg = core.nozzle_svg(spec)
    root = ET.fromstring(svg)
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    n = parse_nozzle(spec)
    assert len(root.findall("{http://www.w3.org/2000/svg}polygon")) >= 1
    facts = core.nozzle_facts(spec)
    assert facts["orifices"] == len(n.footprints) and facts["area"] == pytest.approx(n.area)
    assert facts["turns"] == (not n.is_round)


def test_nozzle_drawing_of_a_bad_spec_is_refused(core):
    with pytest.raises(PrintabilityError, match="an ellipse needs minor="):
        core.nozzle_svg("ellipse:major=0.8")


# ------------------------------------------------------------------ the connect check

MARLIN_3 = ("FIRMWARE_NAME:Marlin 2.1.2.4 (Github) SOURCE_CODE_URL:github.com/MarlinFirmware/"
            "Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:x EXTRUDER_COUNT:1 AXIS_COUNT:3")


def test_axis_check_says_what_stream_says(core):
    from machine_io.protocol import parse_firmware_info
    from machine_io.streaming import StreamingMixin

    rep = core.FirmwareReport()
    assert rep.feed(MARLIN_3) == "m115"
    assert rep.feed("Cap:AUTOREPORT_TEMP:1") == "m115"
    assert rep.feed("ok") is None
    assert rep.feed("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0") == "m114"
    msg = core.axis_problem(rep, "C", "/dev/pts/7", "The rotary G-code")
    assert msg is not None and "\n" not in msg
    assert msg.startswith("The rotary G-code drives a rotary axis C but the printer on "
                          "/dev/pts/7 (Marlin 2.1.2.4 (Github)) reports the axes")
    assert "nothing was sent" in msg
    # the same function printability stream runs
    assert StreamingMixin._check_axes.__qualname__ == "StreamingMixin._check_axes"
    info = parse_firmware_info(rep.lines)
    assert not info.has_axis("C")

    rep.feed("X:0.00 Y:0.00 Z:0.00 C:90.00 E:0.00 Count X:0 Y:0 Z:0 C:900")
    assert core.axis_problem(rep, "C", "/dev/pts/7", "The rotary G-code") is None
    # a new M115 reply starts a new report
    rep.feed(MARLIN_3)
    assert rep.lines == [MARLIN_3]


def test_axis_check_without_any_reply(core):
    msg = core.axis_problem(core.FirmwareReport(), "C", "/dev/ttyUSB0", "The G-code")
    assert "does not report its axes" in msg and "/dev/ttyUSB0" in msg
