"""Every ``--help`` reads whole in an 80-column terminal (issue #23).

Run through the real entry point (the installed ``printability`` script) with
``COLUMNS=80``: no line wider than the terminal, nothing cut short with ``…`` or
``...``, and the SPEC examples each command documents (``ellipse:major=0.8,minor=0.3``,
``ttr:min=-90,max=90``...) printed in one piece, not folded into a narrow column.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from printability.app.cli.main import SUBCOMMANDS

# A SPEC-looking word of the help: a kind, a colon, then key=value pairs.
SPEC_WORD = re.compile(r"\b(?:circle|ellipse|rect|polygon|ttr|xy):[^\s\]]*")

# The examples (and defaults) each command's help must show whole.
SPECS = ("circle:d=0.4", "ellipse:major=0.8,minor=0.3", "rect:w=0.8,h=0.3", "polygon:FILE.svg",
         "ttr:min=-90,max=90")
EXAMPLES = {"analyze": (*SPECS, "slice-outline"), "postprocess": SPECS, "generate": SPECS,
            "demo": ("circle:d=0.8", "ellipse:major=0.8,minor=0.4"),
            "simulate": ("circle:d=0.4", "'drop-ok@12,corrupt~0.01,stall@40:3'",
                         "marlin-advanced")}


def entry_point() -> list[str]:
    """The ``printability`` console script beside this Python (``-m`` when it is absent)."""
    script = Path(sys.executable).with_name("printability")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "printability"]


def subcommand_names() -> list[str]:
    """The subcommands, read from the command the entry point builds."""
    import typer.main

    from printability.app.cli.main import app

    names = list(typer.main.get_command(app).commands)
    assert len(names) == len(SUBCOMMANDS)
    return names


def help_text(*args: str) -> str:
    env = {**os.environ, "COLUMNS": "80", "LINES": "50", "TERM": "xterm", "NO_COLOR": "1"}
    env.pop("TERMINAL_WIDTH", None)
    p = subprocess.run([*entry_point(), *args, "--help"], capture_output=True, text=True,
                       timeout=120, env=env)
    assert p.returncode == 0, p.stderr
    return p.stdout


def assert_whole(text: str) -> None:
    wide = [line for line in text.splitlines() if len(line) > 80]
    assert not wide, "lines wider than 80 columns:\n" + "\n".join(wide)
    assert "…" not in text, text
    # click shortens a command's summary in a list with "..."
    cut = [line for line in text.splitlines()
           if line.rstrip().endswith("...") and not line.startswith("Usage:")]
    assert not cut, "summaries cut short:\n" + "\n".join(cut)


@pytest.mark.parametrize("name", subcommand_names())
def test_subcommand_help_fits_80_columns(name):
    text = help_text(name)
    assert_whole(text)
    flat = " ".join(text.split())
    for spec in EXAMPLES.get(name, ()):
        assert spec in text, f"{name} --help: {spec!r} is not printed whole"
    # every SPEC-like word is a SPEC the library reads: a word folded at a comma is not
    from printability.model.machine import parse_machine
    from printability.model.nozzle import parse_nozzle

    for word in SPEC_WORD.findall(flat):
        word = word.rstrip(".,;'`)")
        if re.search(r"[A-Z]", word) or word.startswith("polygon:pts"):
            continue  # a placeholder (FILE, DEG) or vertices with spaces
        if word.startswith(("ttr", "xy")):
            parse_machine(word)
        else:
            parse_nozzle(word)


def test_top_level_help_fits_80_columns():
    text = help_text()
    assert_whole(text)
    for name in subcommand_names():
        assert re.search(rf"^\s+{name}\s+\S", text, re.M), f"{name} is not listed"
