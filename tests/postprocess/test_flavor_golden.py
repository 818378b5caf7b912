"""Post-processed output per firmware flavor: golden files, and each firmware's documented rules
checked on them (Marlin 2.1 and RepRapFirmware 3 cannot run here; Klipper also runs for real in
tests/firmware)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from gcode.flavors import FLAVORS, flavor_named
from printability.postprocess import PostprocessOptions, postprocess_bytes

HERE = Path(__file__).parent
PART = HERE / "data" / "flavor_part.gcode"
GOLDEN = HERE / "golden"
PROFILE = HERE.parents[1] / "printability" / "data" / "machines" / "ttr.toml"
ELLIPSE = "ellipse:major=0.8,minor=0.3"


def _postprocess(tmp_path: Path, flavor: str) -> str:
    prof = tmp_path / f"ttr-{flavor}.toml"
    prof.write_text(PROFILE.read_text().replace('flavor = "marlin"', f'flavor = "{flavor}"'))
    out, _ = postprocess_bytes(PART.read_bytes(), options=PostprocessOptions(
        nozzle=ELLIPSE, machine=str(prof)))
    return out.decode().replace(str(prof), f"ttr-{flavor}.toml")


def _code(line: str) -> list[str]:
    return line.split(";")[0].split()


@pytest.mark.parametrize("flavor", list(FLAVORS))
def test_golden(tmp_path, flavor):
    text = _postprocess(tmp_path, flavor)
    path = GOLDEN / f"flavor_{flavor}.gcode"
    if os.environ.get("PRINTABILITY_UPDATE_GOLDEN"):  # regenerate on purpose, then review
        path.write_text(text)
    assert path.exists(), f"golden file {path} missing (PRINTABILITY_UPDATE_GOLDEN=1 writes it)"
    assert text == path.read_text()


@pytest.mark.parametrize("flavor", list(FLAVORS))
def test_every_word_is_one_the_firmware_executes_as_meant(tmp_path, flavor):
    f = flavor_named(flavor)
    lines = [_code(ln) for ln in _postprocess(tmp_path, flavor).splitlines()]
    first_c = next(i for i, w in enumerate(lines)
                   if w[:1] in (["G0"], ["G1"]) and any(x.startswith("C") for x in w[1:]))
    setup = [" ".join(w) for w in lines[:first_c] if w]
    if flavor == "klipper":
        # registered, zeroed while unregistered; never G92 C (Klipper ignores it silently)
        assert any("GCODE_AXIS=C" in s and "LIMIT_VELOCITY=" in s for s in setup)
        assert any("SET_POSITION=0" in s for s in setup)
    else:
        assert "G92 C0" in setup
    feed = None
    for i, w in enumerate(lines):
        if not w:
            continue
        cmd = w[0]
        has_c = any(x.startswith("C") for x in w[1:])
        if has_c:
            assert f.rotary_words_allowed(cmd), f"line {i + 1}: {' '.join(w)}"
        if cmd == "G93":
            assert f.inverse_time
        if cmd in ("G0", "G1"):
            axes = {x[0] for x in w[1:]}
            if axes & {"X", "Y", "Z", "E"}:
                if "F" not in axes:
                    # a move without F runs at the feed in force: never a rotation's
                    assert feed != "rotary", f"line {i + 1} inherits a rotation's F: {w}"
                else:
                    feed = "xy"
            elif has_c:
                # a rotation-only move: F in degrees per minute, its own
                assert "F" in axes, f"line {i + 1}: rotation-only move without F"
                feed = "rotary"


def test_flavor_is_in_the_header(tmp_path):
    for flavor in FLAVORS:
        head = _postprocess(tmp_path, flavor).splitlines()[:12]
        assert any(re.search(rf"flavor = {flavor}\b", h) for h in head)
