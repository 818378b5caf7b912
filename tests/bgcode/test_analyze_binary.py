"""Binary G-code as a part (issue #28): ``load_layers`` and ``printability analyze`` read a
``.bgcode`` file (or any file starting with ``GCDE``) as the G-code it holds, with the
results of the same G-code as text; a damaged one is a one-paragraph error."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from bg_helpers import CONFIG_IDS, CONFIGS, PRUSA_DEFAULT

from gcode.bgcode import decode_bgcode
from printability.errors import FileFormatError
from printability.options import SOURCE_FORMATS
from printability.sources import EXTENSIONS, detect_format, load_layers


def _analyze(path, json_out) -> subprocess.CompletedProcess:
    """The real entry point, on a small problem (two nozzles, the raster engine)."""
    r = subprocess.run([sys.executable, "-m", "printability", "analyze", str(path),
                        "-n", "circle:d=0.4", "-n", "ellipse:major=0.8,minor=0.3", "-m", "ttr",
                        "--engine", "raster", "--resolution", "0.1", "-j", "1",
                        "--no-progress", "--json", str(json_out)],
                       capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONUNBUFFERED": "1"})
    r.stderr = " ".join(r.stderr.split())  # the error paragraph is wrapped for a terminal
    return r


def _same_layers(a, b) -> None:
    """Equal stacks but for where each layer starts in its file (the binary file's G-code has
    neither the thumbnails nor the header comments of the text, so its lines come earlier)."""
    assert len(a) == len(b) > 0
    for x, y in zip(a, b, strict=True):
        assert (x.z, x.height, x.index) == (y.z, y.height, y.index)
        assert x.region.equals(y.region) and x.area == y.area
        assert {k: v for k, v in x.meta.items() if k != "line"} == \
            {k: v for k, v in y.meta.items() if k != "line"}
    assert a.meta == b.meta


def test_bgcode_is_a_gcode_source():
    assert EXTENSIONS[".bgcode"] == "gcode"
    assert ".bgcode" in dict(SOURCE_FORMATS.entries)["gcode"]


@pytest.mark.parametrize(("compression", "encoding"), CONFIGS, ids=CONFIG_IDS)
def test_layers_of_binary_gcode_are_those_of_the_text(sample_text, sample_binary, tmp_path,
                                                      compression, encoding):
    text, binary = tmp_path / "part.gcode", tmp_path / "part.bgcode"
    binary.write_bytes(sample_binary("short", compression, encoding))
    assert detect_format(binary) == "gcode"
    layers = load_layers(binary)
    # the G-code it holds, as a text file: the same layers, line numbers and all
    text.write_bytes(decode_bgcode(binary.read_bytes()).text_form())
    same = load_layers(text)
    assert [lay.meta for lay in same] == [lay.meta for lay in layers]
    _same_layers(same, layers)
    if encoding != 1:
        # and those of the text it was made from; MeatPack without comments (encoding 1)
        # drops every comment, the layer changes and line widths among them, by design
        text.write_bytes(sample_text("short"))
        _same_layers(load_layers(text), layers)


@pytest.mark.parametrize("name", ["part.txt", "part.stl", "part.gcode", "part.dat", "part"])
def test_binary_gcode_is_recognised_whatever_its_name(sample_text, sample_binary, tmp_path,
                                                       name):
    text = tmp_path / "text.gcode"
    text.write_bytes(sample_text("short"))
    binary = tmp_path / name
    binary.write_bytes(sample_binary("short", *PRUSA_DEFAULT))
    assert detect_format(binary) == "gcode"
    _same_layers(load_layers(text), load_layers(binary))


def test_a_damaged_binary_file_is_a_file_format_error(sample_binary, tmp_path):
    data = bytearray(sample_binary("short", *PRUSA_DEFAULT))
    g = decode_bgcode(bytes(data)).gcode_blocks[-1]
    data[g.data + 10] ^= 0x01
    bad = tmp_path / "part.bgcode"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError) as e:
        load_layers(bad)
    assert f"G-code block {g.index + 1} (byte {g.start}) fails its CRC32 check" in str(e.value)


def test_analyze_gives_the_same_result_for_the_binary_file(sample_text, sample_binary,
                                                          tmp_path):
    text, binary = tmp_path / "part.gcode", tmp_path / "part.bgcode"
    text.write_bytes(sample_text("short"))
    binary.write_bytes(sample_binary("short", *PRUSA_DEFAULT))
    results = []
    for path in (text, binary):
        r = _analyze(path, tmp_path / f"{path.suffix[1:]}.json")
        assert r.returncode == 0, r.stderr
        assert "Traceback" not in r.stderr
        doc = json.loads((tmp_path / f"{path.suffix[1:]}.json").read_text())
        assert doc["input"] == str(path)
        results.append({k: v for k, v in doc.items() if k not in ("input", "elapsed_s")})
    assert results[0] == results[1]
    assert results[0]["layers"] == 4 and len(results[0]["nozzles"]) == 2


def _damaged(data: bytes, how: str) -> tuple[bytes, str]:
    """``data`` damaged ``how``, and what the message says of it."""
    g = decode_bgcode(data).gcode_blocks[0]
    if how == "crc":
        bad = bytearray(data)
        bad[g.data + 100] ^= 0x40
        return bytes(bad), f"G-code block {g.index + 1} (byte {g.start}) fails its CRC32 check"
    return data[:g.start + 50], (f"the file is cut off in G-code block {g.index + 1} (byte "
                                 f"{g.start})")


@pytest.mark.parametrize("how", ["crc", "truncated"])
def test_analyze_refuses_a_damaged_binary_file_in_one_paragraph(sample_binary, tmp_path, how):
    data, said = _damaged(sample_binary("short", *PRUSA_DEFAULT), how)
    bad = tmp_path / "part.bgcode"
    bad.write_bytes(data)
    r = _analyze(bad, tmp_path / "r.json")
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.startswith("printability: error:") and "Traceback" not in r.stderr
    assert r.stderr.count("printability: error:") == 1
    assert "part.bgcode: damaged binary G-code (.bgcode)" in r.stderr and said in r.stderr
    assert not (tmp_path / "r.json").exists()
