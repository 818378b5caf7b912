"""printability.analysis: per-layer analysis, ranking, JSON contract, report."""

from __future__ import annotations

import json
import math

import pytest
from shapely.geometry import MultiPolygon, box

from printability.analysis import analyze
from printability.errors import InputError
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack


def _stack(*regions, height=0.2):
    layers = tuple(Layer(z=height * (i + 1), height=height, region=as_region(r), index=i)
                   for i, r in enumerate(regions))
    return LayerStack(layers, source="synthetic")


def test_rectangle_closed_form_and_json_contract():
    r = 0.4
    stack = LayerStack((Layer(0.0, 0.0, MultiPolygon([box(0, 0, 10, 5)]), 0),), source="rect")
    a = analyze(stack, [f"circle:d={2 * r}"], "xy")
    doc = a.to_json()
    json.dumps(doc, allow_nan=False)
    assert doc["units"] == "mm" and doc["machine"] == "xy"
    (n,) = doc["nozzles"]
    exact = (4 - math.pi) * r * r
    lo, hi = n["lost_area_bounds"]
    assert lo <= exact <= hi
    assert n["lost_area"] == pytest.approx(exact, rel=1e-2)  # conservative: S_inner
    assert n["rank"] == 1 and n["components"] == 1
    assert "target_volume" not in n  # one planar layer: areas only
    assert n["layers"][0]["target_area"] == pytest.approx(50.0)


def test_ranking_and_volumes_over_layers():
    # a 0.5 mm wide strip on top of a plate: the 0.8 mm circle loses the strip layer
    stack = _stack(box(0, 0, 20, 10), box(0, 0, 20, 0.5))
    a = analyze(stack, ["circle:d=0.8", "circle:d=0.4"], "xy")
    first, second = a.nozzles
    assert (first.nozzle.spec, second.nozzle.spec) == ("circle:d=0.4", "circle:d=0.8")
    assert (first.rank, second.rank) == (1, 2)
    doc = a.to_json()["nozzles"][1]
    assert doc["layers"][1]["lost_area"] == pytest.approx(10.0)   # the whole strip
    assert doc["lost_volume"] == pytest.approx(sum(
        lay["lost_area"] * 0.2 for lay in doc["layers"]))
    assert doc["target_volume"] == pytest.approx((200 + 10) * 0.2)


def test_nozzle_larger_than_a_layer_loses_that_layer():
    stack = _stack(box(0, 0, 10, 10), box(0, 0, 0.3, 0.3))
    a = analyze(stack, ["circle:d=1"], "xy")
    top = a.nozzles[0].layers[1]
    assert top.as_built_area == 0 and top.lost_area == pytest.approx(0.09)
    assert "larger than the layer" in top.note


def test_ellipse_threads_a_slot_only_when_it_can_turn():
    # slot 0.5 wide: between the minor (0.3) and major (0.8) axes; the major axis lies along x
    slot = box(0, 0, 0.5, 10)
    stack = _stack(slot)
    xy = analyze(stack, ["ellipse:major=0.8,minor=0.3"], "xy").nozzles[0]
    ttr = analyze(stack, ["ellipse:major=0.8,minor=0.3"], "ttr", engine="exact").nozzles[0]
    assert xy.as_built_area == 0
    assert ttr.lost_fraction < 0.05


def test_no_nozzle_is_an_error():
    with pytest.raises(InputError, match="at least one nozzle"):
        analyze(_stack(box(0, 0, 1, 1)), [], "xy")


def test_parallel_workers_give_the_same_numbers():
    from printability.settings import Settings

    stack = _stack(box(0, 0, 5, 5), box(0, 0, 5, 1), box(1, 1, 4, 4))
    one = analyze(stack, ["circle:d=0.6"], "xy").to_json()
    two = analyze(stack, ["circle:d=0.6"], "xy", settings=Settings(workers=2)).to_json()
    for a, b in zip(one["nozzles"][0]["layers"], two["nozzles"][0]["layers"], strict=True):
        assert a == b


def test_report_is_written(tmp_path):
    pytest.importorskip("matplotlib")
    from printability.analysis.report import write_report

    stack = _stack(box(0, 0, 10, 5), box(0, 0, 10, 0.6))
    a = analyze(stack, ["circle:d=0.8", "ellipse:major=0.8,minor=0.3"], "ttr", engine="exact")
    index = write_report(a, tmp_path / "rep")
    page = index.read_text()
    for n in (1, 2):
        assert (tmp_path / "rep" / f"nozzle{n}_layer.png").stat().st_size > 1000
        assert (tmp_path / "rep" / f"nozzle{n}_as_built.geojson").is_file()
        assert (tmp_path / "rep" / f"nozzle{n}_as_built.stl").is_file()
        assert f"nozzle{n}_layer.png" in page
    assert (tmp_path / "rep" / "lost_per_layer.png").is_file()
    gj = json.loads((tmp_path / "rep" / "nozzle1_as_built.geojson").read_text())
    assert len(gj["features"]) == 2
    assert not list((tmp_path / "rep").glob(".*.tmp"))  # atomic writes leave no temp files
