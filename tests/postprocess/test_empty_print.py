"""A nozzle that prints none of the part is an error (exit 1, the slicer's file untouched),
unless the user asks for the empty file."""

from __future__ import annotations

import subprocess
import sys

import pytest

from printability.errors import NozzleTooLargeError
from printability.postprocess import PostprocessOptions, postprocess_bytes


def test_library_refuses_an_empty_print(prusa_short):
    data = prusa_short.read_bytes()
    with pytest.raises(NozzleTooLargeError, match="can print none of the part's"):
        postprocess_bytes(data, options=PostprocessOptions(nozzle="circle:d=30"))
    _, res = postprocess_bytes(data, options=PostprocessOptions(nozzle="circle:d=30",
                                                                 allow_empty=True))
    assert res.dropped_moves > 0 and not any(r.printed_length > 1e-6 for r in res.layers)


def test_cli_exits_1_and_leaves_the_file(prusa_short, tmp_path):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    before = path.read_bytes()
    r = subprocess.run([sys.executable, "-m", "printability", "postprocess", str(path),
                        "--nozzle", "circle:d=30"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr and "--allow-empty" in r.stderr
    assert path.read_bytes() == before
    assert not list(tmp_path.glob(".*tmp"))
