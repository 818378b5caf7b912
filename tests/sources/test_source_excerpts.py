"""User input quoted in errors is a short escaped excerpt (issue #24, item 3):
:func:`printability.errors.excerpt` and the SVG reader's messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from printability.errors import EXCERPT_LENGTH, FileFormatError, excerpt
from printability.sources import detect_format
from printability.sources.svg import load_svg_layers


@pytest.mark.parametrize("value, expected", [
    ("G1 X1", "'G1 X1'"),
    ("a\x01b\tc\u202ed", "'a\\x01b\\tc\\u202ed'"),
    (b"M117 \xff\x00", "'M117 \\xff\\x00'"),
    ("x" * (EXCERPT_LENGTH + 1), "'" + "x" * EXCERPT_LENGTH + "'…"),
    ("", "''"),
])
def test_excerpt(value, expected):
    assert excerpt(value) == expected


def test_excerpt_of_ten_megabytes_is_short():
    assert len(excerpt("\x00" * 10_000_000)) <= 4 * EXCERPT_LENGTH + 3


def _svg(tmp_path: Path, body: str, extra: str = "") -> Path:
    path = tmp_path / "t.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" '
                    f'xmlns:slic3r="http://slic3r.org/namespaces/slic3r" {extra}>{body}</svg>')
    return path


def test_a_huge_slic3r_z_is_quoted_short(tmp_path):
    path = _svg(tmp_path, f'<g id="{"i" * 100_000}" slic3r:z="{"9" * 5 + "x" * 100_000}">'
                '<polygon points="0,0 1,0 1,1"/></g>')
    with pytest.raises(FileFormatError) as e:
        load_svg_layers(path)
    assert "expected a number in slic3r:z" in str(e.value) and len(str(e.value)) < 1000


def test_a_long_unknown_extension_is_quoted_short(tmp_path):
    path = tmp_path / ("part." + "q" * 200)
    path.write_bytes(b"\x01\x02 nothing known")
    with pytest.raises(FileFormatError) as e:
        detect_format(path)
    assert "'.qqqq" in str(e.value) and "q" * 100 not in str(e.value).split(":", 1)[1]
