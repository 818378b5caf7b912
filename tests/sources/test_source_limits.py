"""Work that is neither refused nor finished (issue #24, item 4): an SVG that expands beyond
the limits is refused before it is built, naming the element, and an analysis whose raster
work is beyond the budget is refused before the engine runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import printability.analysis.tasks as analysis_tasks
from printability.analysis import RASTER_WORK_BUDGET, analyze, raster_work
from printability.errors import FileFormatError, ResourceError
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings
from printability.sources.svg import (
    MAX_DEPTH,
    MAX_ELEMENTS,
    check_expansion,
    load_svg_layers,
    load_svg_region,
)

HEAD = ('<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
        'width="10mm" height="10mm" viewBox="0 0 10 10">')


def _write(tmp_path: Path, body: str, name: str = "t.svg") -> Path:
    path = tmp_path / name
    path.write_text(HEAD + body + "</svg>")
    return path


def use_bomb(levels: int = 11) -> str:
    """Ten copies of the level below at each level: 10^levels rectangles in about 1.4 kB."""
    body = '<defs><rect id="a0" width="1" height="1"/>'
    for i in range(1, levels + 1):
        body += f'<g id="a{i}">' + f'<use xlink:href="#a{i - 1}"/>' * 10 + "</g>"
    return body + f'</defs><use xlink:href="#a{levels}"/>'


def test_nested_use_is_refused_before_anything_is_copied(tmp_path):
    path = _write(tmp_path, use_bomb())
    assert path.stat().st_size < 3000
    with pytest.raises(ResourceError) as e:
        load_svg_layers(path)
    message = str(e.value)
    assert message.startswith(f"{path}, <use href='#a11'>:")
    assert "222,222,222,222 elements" in message and f"{MAX_ELEMENTS:,} allowed" in message


def test_ninety_thousand_rectangles_are_refused(tmp_path):
    body = "".join(f'<rect x="{i % 300}" y="{i // 300}" width="0.5" height="0.5"/>'
                   for i in range(90_000))
    path = _write(tmp_path, body)
    with pytest.raises(ResourceError, match=r"<svg>: this draws 90,001 elements"):
        load_svg_layers(path)


def test_a_use_of_its_own_ancestor_is_refused(tmp_path):
    path = _write(tmp_path, '<g id="a"><rect width="1" height="1"/><use xlink:href="#a"/></g>')
    with pytest.raises(FileFormatError, match=r"<use href='#a'>: refers to <g id='a'>"):
        load_svg_layers(path)


def test_deep_nesting_is_refused_and_counting_does_not_recurse(tmp_path):
    deep = 20_000  # far beyond Python's recursion limit
    path = _write(tmp_path, "<g>" * deep + '<rect width="1" height="1"/>' + "</g>" * deep)
    with pytest.raises(ResourceError, match=f"nested {deep + 2:,} deep, more than the "
                                            f"{MAX_DEPTH} levels"):
        load_svg_layers(path)


def test_what_is_within_the_limits_is_counted_and_drawn(tmp_path):
    path = _write(tmp_path, use_bomb(3))
    from defusedxml import ElementTree

    elements, points = check_expansion(path, ElementTree.parse(path).getroot())
    a = 1  # the rect; each level: its <g> and ten <use>, each a copy of the level below
    for _ in range(3):
        a = 1 + 10 * (1 + a)
    assert elements == 1 + 1 + a  # the <svg>, the last <use>, what it copies
    assert points == 4 * 1000
    assert load_svg_layers(path)[0].area == pytest.approx(1.0)  # the copies overlap


@pytest.mark.parametrize("radius", ["1e12", "1e15"])
def test_a_curve_too_large_for_its_tolerance_is_refused(tmp_path, radius):
    # 1e15: 1 − tol/r rounds to 1 (ZeroDivisionError before); 1e12: billions of points
    path = _write(tmp_path, f'<circle cx="5" cy="5" r="{radius}"/>')
    with pytest.raises(ResourceError, match=r"<circle> #1: flattening the curves"):
        load_svg_layers(path)


def test_the_limits_hold_for_a_nozzle_polygon_too(tmp_path):
    path = _write(tmp_path, use_bomb())
    with pytest.raises(ResourceError):
        load_svg_region(path)


# ---------------------------------------------------------------- raster work


@pytest.fixture
def square(tmp_path):
    return load_svg_layers(_write(tmp_path, '<rect width="10" height="10"/>', "square.svg"))


def test_a_resolution_too_fine_is_refused_before_the_engine_runs(square, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("an engine ran")

    monkeypatch.setattr(analysis_tasks, "compute_mmc", never)
    with pytest.raises(ResourceError) as e:
        analyze(square, ["ellipse:major=0.8,minor=0.3"], "ttr",
                settings=Settings(resolution=1e-3))
    message = str(e.value)
    assert "layer 0" in message and "ellipse:major=0.8,minor=0.3" in message
    assert "--resolution 0.001 mm" in message and "× 90 angle(s)" in message
    assert "Use --resolution 0.002 or coarser" in message and "--angle-step" in message


def test_the_suggested_resolution_fits_the_budget(square):
    noz, mach = parse_nozzle("rect:w=0.8,h=0.3"), parse_machine("ttr")
    fine, _ = raster_work(square[0].region.bounds, noz, mach, Settings(resolution=1e-3))
    ok, _ = raster_work(square[0].region.bounds, noz, mach, Settings(resolution=2e-3))
    assert fine > RASTER_WORK_BUDGET > ok
    # the work grows as resolution⁻³ once the kernel is wider than a word
    assert fine / ok == pytest.approx(8, rel=0.05)


def test_engines_that_do_not_rasterise_are_not_refused(square):
    # a round nozzle on an XY machine goes to the exact engine, whatever the resolution
    result = analyze(square, ["circle:d=0.4"], "xy", settings=Settings(resolution=1e-3))
    assert result.engine == "exact"


def test_analyze_command_says_so_in_one_paragraph(tmp_path):
    _write(tmp_path, '<rect width="10" height="10"/>', "square.svg")
    r = subprocess.run([sys.executable, "-m", "printability", "analyze",
                        str(tmp_path / "square.svg"), "--resolution", "1e-3", "-m", "ttr", "-n",
                        "ellipse:major=0.8,minor=0.3", "--no-progress", "-j", "1"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "printability: error:" in r.stderr and "raster engine would do about" in r.stderr


# ---------------------------------------------------------------- found by tests/fuzz


def test_a_root_in_another_namespace_is_refused(tmp_path):
    path = tmp_path / "ns.svg"
    path.write_text('<svg xmlns="http://www.w3.org//svg" viewBox="0 0 9 9"><rect width="1" '
                    'height="1"/></svg>')  # a mutated xmlns: AttributeError before
    with pytest.raises(FileFormatError, match="expected the SVG namespace"):
        load_svg_layers(path)


@pytest.mark.parametrize("d", ["T 0 0", "S 1 1 2 2", "C 1 1 2 2 3 3 L 5 5 z"])
def test_a_curve_with_no_current_point_is_no_crash(tmp_path, d):
    # svgelements leaves the start of such a curve None (AttributeError before)
    with pytest.raises(FileFormatError, match="no closed shape"):
        load_svg_layers(_write(tmp_path, f'<path d="{d}"/>'))


@pytest.mark.parametrize("attrs", ['width="1" height="1e309"', 'x="1e16" width="1" height="1"',
                                   'points="0,0 1,0 1e309,1"'])
def test_corners_out_of_range_are_refused(tmp_path, attrs):
    # straight edges were not checked: GEOSException (NaN/Inf) before
    tag = "polygon" if "points" in attrs else "rect"
    with pytest.raises(FileFormatError, match=r"a coordinate of this shape is"):
        load_svg_layers(_write(tmp_path, f"<{tag} {attrs}/>"))


def test_boxes_are_only_computed_for_fit(tmp_path, monkeypatch):
    # a millisecond per arc: 1000 copies of an icon took 54 s before anything else
    import svgelements

    def no_box(self, *args, **kwargs):
        raise AssertionError("bbox computed without fit")

    path = _write(tmp_path, '<path d="M1 1 A 2 2 0 0 1 5 5 L 1 5 z"/>')
    monkeypatch.setattr(svgelements.Shape, "bbox", no_box)
    assert load_svg_layers(path)[0].area > 0
