"""Refinement in analyze: a bound tolerance the user sets, ties that separate, and intervals
that only shrink and always hold the exact value."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
import shapely
from shapely.geometry import MultiPolygon, box

from printability.analysis import BoundTolerance, RefineOptions, analyze
from printability.errors import InputError, ResourceError
from printability.mmc import compute_mmc
from printability.mmc.refine import merge_bounds, refined_settings
from printability.mmc.result import MMCInternalError
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack
from printability.settings import Settings


def rect_stack(w=10.0, h=4.0, heights=(0.0,)):
    g = MultiPolygon([box(0, 0, w, h)])
    return LayerStack(tuple(Layer(0.2 * (i + 1) if t else 0.0, t, g, i)
                            for i, t in enumerate(heights)), source="rectangle")


def comb():
    """Teeth 0.3, 0.5, 0.8, 1.2 and 2.0 mm wide, 5 mm long, on a 2 mm spine (the comb of
    tests/mmc/shapes.py)."""
    parts, x = [], 0.0
    for w in (0.3, 0.5, 0.8, 1.2, 2.0):
        parts.append(box(x, 2.0, x + w, 7.0))
        x += w + 1.0
    parts.append(box(0.0, 0.0, x - 1.0, 2.0 + 1e-9))
    return as_region(shapely.union_all(parts))


def rounded_loss(d):
    """A rectangle opened by a disk of diameter d loses (4 − π)(d/2)² (exactly)."""
    return (4 - math.pi) * (d / 2) ** 2


@pytest.mark.parametrize("text,value,relative", [
    ("0.5", 0.5, False), (0.25, 0.25, False), ("5%", 0.05, True), (" 100% ", 1.0, True)])
def test_tolerance_parses(text, value, relative):
    t = BoundTolerance.parse(text)
    assert (t.value, t.relative) == (pytest.approx(value), relative)


@pytest.mark.parametrize("bad", ["0", "-1", "abc", "nan", "inf", "150%", "%", ""])
def test_bad_tolerances_are_refused(bad):
    with pytest.raises(InputError, match="bound tolerance"):
        BoundTolerance.parse(bad)


def test_relative_tolerance_has_a_floor_of_the_part():
    from printability.analysis.ranking import Totals

    t = BoundTolerance.parse("5%")
    assert t.allowed(Totals("area", "mm²", 100.0, 10.0, (9.0, 11.0))) == pytest.approx(0.5)
    # nothing lost: 5 % of 0 could never be met; 0.05 % of the part is
    assert t.allowed(Totals("area", "mm²", 100.0, 0.0, (0.0, 0.1))) == pytest.approx(0.05)


def test_merge_keeps_the_tighter_ends_and_refuses_disjoint_intervals():
    assert merge_bounds((1.0, 5.0), (2.0, 7.0), target_area=10.0) == (2.0, 5.0)
    # missing each other by rounding only: they meet
    lo, hi = merge_bounds((1.0, 2.0), (2.0 + 1e-12, 3.0), target_area=10.0)
    assert lo == hi == pytest.approx(2.0)
    with pytest.raises(MMCInternalError, match="disjoint"):
        merge_bounds((1.0, 2.0), (2.1, 3.0), target_area=10.0)


def test_refined_settings_per_engine():
    from printability.model.machine import parse_machine
    from printability.model.nozzle import parse_nozzle

    ell, circ = parse_nozzle("ellipse:major=0.8,minor=0.3"), parse_nozzle("circle:d=0.4")
    ttr, xy = parse_machine("ttr:step=4"), parse_machine("xy")
    s = Settings(resolution=0.04)
    r = refined_settings("raster", ell, ttr, s)
    assert (r.resolution, r.angle_step) == (0.02, 2.0)
    r = refined_settings("raster", circ, ttr, s)  # a round nozzle does not turn
    assert (r.resolution, r.angle_step) == (0.02, None)
    assert refined_settings("exact", ell, ttr, s).angle_step == 2.0
    assert refined_settings("exact", circ, xy, s).quad_segs == 2 * s.quad_segs
    assert refined_settings("sampled", circ, xy, s) is None


def test_an_absolute_tolerance_is_met_and_the_bounds_hold_the_exact_value():
    d = 1.0
    tol = 0.003
    settings = Settings(resolution=0.1)
    coarse = analyze(rect_stack(), [f"circle:d={d}"], "xy", engine="raster", settings=settings)
    lo, hi = coarse.nozzles[0].lost_area_bounds
    assert hi - lo > tol  # the premise: too wide at h = 0.1
    a = analyze(rect_stack(), [f"circle:d={d}"], "xy", engine="raster", settings=settings,
                refine=RefineOptions(bound_tolerance=tol))
    n = a.nozzles[0]
    lo, hi = n.lost_area_bounds
    assert hi - lo <= tol and n.tolerance_met and a.refinement.met
    assert lo <= rounded_loss(d) <= hi
    assert a.refinement.rounds >= 1 and a.refinement.stopped == "met"
    assert n.layers[0].refinements == a.refinement.rounds
    assert n.layers[0].resolution == pytest.approx(0.1 / 2 ** a.refinement.rounds)
    doc = a.to_json()
    json.dumps(doc, allow_nan=False)
    assert doc["refinement"]["met"] is True and doc["refinement"]["tasks"] >= 1
    bt = doc["nozzles"][0]["bound_tolerance"]
    assert bt["met"] and bt["width"] <= bt["allowed_width"] == tol and bt["unit"] == "mm²"


def test_a_relative_tolerance_over_layers_is_in_volume():
    # a square nozzle's band is not settled below the pixel: its raster interval is wide
    stack = LayerStack(tuple(Layer(0.2 * (i + 1), t, as_region(comb()), i)
                             for i, t in enumerate((0.2, 0.3))), source="comb")
    spec = "rect:w=0.6,h=0.6"
    a = analyze(stack, [spec], "xy", engine="raster", settings=Settings(resolution=0.1),
                refine=RefineOptions(bound_tolerance="50%"))
    n = a.nozzles[0]
    t = n.totals()
    assert t.unit == "mm³" and n.tolerance_met and a.refinement.rounds >= 1
    assert n.allowed_width == pytest.approx(max(0.5 * t.lost, 0.005 * t.target))
    assert t.lost_bounds[1] - t.lost_bounds[0] <= n.allowed_width
    ex = compute_mmc(comb(), spec, "xy", engine="exact").lost_area_bounds
    assert t.lost_bounds[0] <= ex[1] * 0.5 + 1e-9 and ex[0] * 0.5 <= t.lost_bounds[1] + 1e-9
    doc = a.to_json()["nozzles"][0]
    assert doc["lost_volume_bounds"] == pytest.approx(list(t.lost_bounds))


def test_a_tolerance_beyond_the_memory_guard_is_refused_up_front():
    settings = Settings(resolution=0.05, max_memory=64 << 20)
    with pytest.raises(ResourceError, match=r"MiB.*nothing was refined"):
        analyze(rect_stack(40, 40), ["circle:d=1.0"], "xy", engine="raster",
                settings=settings, refine=RefineOptions(bound_tolerance=1e-4))


def test_ties_separate_when_refined_and_the_exact_values_stay_inside():
    # square nozzles (no band settling): the small one prints every tooth of the comb,
    # the large one loses the two narrowest; at h = 0.1 their intervals overlap
    small, large = "rect:w=0.25,h=0.25", "rect:w=0.6,h=0.6"
    stack = LayerStack((Layer(0.0, 0.0, as_region(comb()), 0),), source="comb")
    settings = Settings(resolution=0.1)
    plain = analyze(stack, [small, large], "xy", engine="raster", settings=settings)
    assert plain.ties  # coarse intervals overlap
    assert [n.rank_range for n in plain.nozzles] == [(1, 2), (1, 2)]
    a = analyze(stack, [small, large], "xy", engine="raster", settings=settings,
                refine=RefineOptions(separate_ties=True, refine_budget=1000))
    assert not a.ties and a.refinement.stopped == "separated"
    assert [n.rank_range for n in a.nozzles] == [(1, 1), (2, 2)]
    assert [n.nozzle.spec for n in a.nozzles] == [small, large]
    for n in a.nozzles:
        lo, hi = n.lost_area_bounds
        elo, ehi = compute_mmc(comb(), n.nozzle.spec, "xy", engine="exact").lost_area_bounds
        assert lo <= ehi + 1e-9 and elo <= hi + 1e-9
    doc = a.to_json()
    assert doc["ranking"]["certain"] and doc["nozzles"][0]["rank_range"] == [1, 1]


def test_tie_separation_stays_within_its_budget():
    stack = LayerStack((Layer(0.0, 0.0, as_region(comb()), 0),), source="comb")
    a = analyze(stack, ["rect:w=0.25,h=0.25", "rect:w=0.6,h=0.6"], "xy", engine="raster",
                settings=Settings(resolution=0.1),
                refine=RefineOptions(separate_ties=True, refine_budget=0.0))
    assert a.refinement.rounds == 0 and a.refinement.stopped == "budget"
    assert a.ties  # still tied, and said so


def test_cli_bound_tolerance_reports_what_was_met(tmp_path):
    src = tmp_path / "rect.wkt"
    src.write_text("POLYGON ((0 0, 10 0, 10 4, 0 4, 0 0))")
    out = tmp_path / "r.json"
    p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src), "-n",
                        "circle:d=1.0", "--engine", "raster", "--resolution", "0.1",
                        "--bound-tolerance", "0.003", "--json", str(out), "--no-progress"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "bound tolerance 0.003: met" in p.stdout and "refinement:" in p.stdout
    doc = json.loads(out.read_text())
    assert doc["refinement"]["met"] is True
    p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src),
                        "--bound-tolerance", "lots", "--no-progress"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 1 and "bound tolerance" in p.stderr and "Traceback" not in p.stderr
