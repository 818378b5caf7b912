"""The slicer-settings scan of the post-processor finds what a regular-expression search finds.

Oracle: ``re.search`` with ``^`` and ``re.MULTILINE`` (what the scan replaced), on
generated files mixing settings comments, near misses and blanks.
"""

from __future__ import annotations

import re

from hypothesis import example, given, settings
from hypothesis import strategies as st

from printability.postprocess import already_processed
from printability.postprocess.scan import config_value


def _regex_value(data: bytes, key: str) -> float | None:
    m = re.search(rb"^;\s*" + re.escape(key.encode()) + rb"\s*=\s*([-+0-9.eE]+)", data,
                  re.MULTILINE)
    if not m:
        return None
    try:
        return float(m.group(1))
    except ValueError:
        return None


_piece = st.sampled_from([
    b"; nozzle_diameter = 0.4", b";nozzle_diameter=0.6", b"; nozzle_diameter = ",
    b"; nozzle_diameter = 1e", b"nozzle_diameter = 0.5", b" ; nozzle_diameter = 0.7",
    b";\n nozzle_diameter = 0.8", b"; nozzle_diameter_x = 0.9", b"; filament_diameter = 1.75",
    b"G1 X1 ; nozzle_diameter = 0.3", b";", b"", b" ", b"\t", b"\r", b"\x0b",
    b"; printability 0.1.0 postprocessed this file", b" ; printability 0.1 postprocessed this file",
    b"; printability postprocessed this file", b";; printability 1 postprocessed this file",
])


@settings(max_examples=500)
@given(st.lists(_piece, max_size=12), st.sampled_from([b"\n", b"\r\n", b"\r"]))
@example([b";\n nozzle_diameter = 0.8"], b"\n")
def test_settings_scan_is_the_regex(pieces, eol):
    data = eol.join(pieces)
    for key in ("nozzle_diameter", "filament_diameter"):
        assert config_value(data, key) == _regex_value(data, key), data
    marker = re.search(rb"^; printability \S+ postprocessed this file", data, re.MULTILINE)
    assert already_processed(data) == (marker is not None), data
