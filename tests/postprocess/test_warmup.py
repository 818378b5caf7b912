"""``printability warmup`` compiles the plug-in's kernels on a part that takes its code paths."""

from __future__ import annotations

import subprocess
import sys

from gcode import parse_gcode
from printability.app.warmup import warm_up_gcode
from printability.postprocess import PostprocessOptions, postprocess_bytes


def test_the_warm_up_part_takes_the_plugins_paths():
    for relative in (True, False):
        data = warm_up_gcode(relative_e=relative)
        g = parse_gcode(data)
        assert len(g.layers) == 3
        _, res = postprocess_bytes(data, options=PostprocessOptions(
            nozzle="ellipse:major=0.8,minor=0.3", machine="ttr"))
        # turns (the outline's corners: its inner wall and infill lie wider rather than
        # turn) and split moves (the planner's split and the rewrite's new lines)
        assert res.rotary_words > 5
        assert res.split_moves > 10
        assert res.changed_lines >= res.split_moves


def test_warmup_command():
    out = subprocess.run([sys.executable, "-m", "printability", "warmup"], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "kernels compiled and cached: 5 runs" in out.stdout
    assert out.stderr.count("warm-up: post-processing for") == 4
    assert out.stderr.count("warm-up: generating for ellipse") == 1
