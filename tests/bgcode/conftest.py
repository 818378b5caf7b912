"""Binary G-code made from the shared samples, once per session."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from bg_helpers import binarize, with_thumbnails

# the post-processing tests' helpers (deposition targets, kept lines) serve here too
sys.path.append(str(Path(__file__).resolve().parents[1] / "postprocess"))

PRUSA_SAMPLE = "prusaslicer_2.7.4_marlin2_arcs.gcode"


def short_prusa_text(path: Path, layers: int) -> bytes:
    """The first ``layers`` layers of a PrusaSlicer file followed by its closing metadata
    and settings (what the slicer writes after the last layer)."""
    data = path.read_bytes()
    tail = data.find(b"\n; filament used [mm]")
    assert tail > 0
    pos = -1
    for _ in range(layers + 1):
        pos = data.find(b"\n;LAYER_CHANGE", pos + 1)
    return data[:pos + 1] + data[tail + 1:]


@pytest.fixture(scope="session")
def sample_text(shared_data: Path) -> Callable[[str], bytes]:
    """A shared sample's text (``"short"``: the PrusaSlicer sample's first 4 layers)."""
    cache: dict[str, bytes] = {}

    def get(name: str) -> bytes:
        if name not in cache:
            cache[name] = short_prusa_text(shared_data / "gcode" / PRUSA_SAMPLE, 4) \
                if name == "short" else (shared_data / "gcode" / name).read_bytes()
        return cache[name]

    return get


@pytest.fixture(scope="session")
def sample_binary(sample_text) -> Callable[[str, int, int], bytes]:
    """A shared sample (or ``"short"``) with thumbnails, made binary by libbgcode with the
    given compression and encoding."""
    cache: dict[tuple[str, int, int], bytes] = {}

    def get(name: str, compression: int, encoding: int) -> bytes:
        key = (name, compression, encoding)
        if key not in cache:
            cache[key] = binarize(with_thumbnails(sample_text(name)), compression, encoding)
        return cache[key]

    return get
