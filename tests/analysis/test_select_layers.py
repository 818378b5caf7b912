"""select_layers: the --layers syntax."""

from __future__ import annotations

import pytest
from shapely.geometry import box

from printability.analysis import select_layers
from printability.errors import InputError
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack

STACK = LayerStack(tuple(Layer(z=0.2 * (i + 1), height=0.2, region=as_region(box(0, 0, 1 + i, 1)),
                               index=i) for i in range(10)), source="ten")


@pytest.mark.parametrize(("spec", "kept"), [
    ("0", [0]),
    ("-1", [9]),
    ("3-5", [3, 4, 5]),
    ("-3-9", [7, 8, 9]),
    ("::4", [0, 4, 8]),
    ("7:", [7, 8, 9]),
    (":2,9", [0, 1, 9]),
    ("5, 2, 5", [2, 5]),
])
def test_selection(spec, kept):
    s = select_layers(STACK, spec)
    assert [lay.meta["source_index"] for lay in s] == kept
    assert [lay.index for lay in s] == list(range(len(kept)))      # renumbered
    assert [lay.z for lay in s] == [STACK[i].z for i in kept]
    assert [lay.area for lay in s] == [STACK[i].area for i in kept]
    assert s.meta["selected_layers"] == kept


@pytest.mark.parametrize(("spec", "needle"), [
    ("10", "layer 10 does not exist"),
    ("-11", "layer -11 does not exist"),
    ("x", "'x' is not a number"),
    ("1:2:0", "is not a slice"),
    ("1:2:3:4", "is not a slice"),
    ("5:2", "no layer selected"),
    ("4-20", "layer 20 does not exist"),
])
def test_bad_selection(spec, needle):
    with pytest.raises(InputError, match=needle) as info:
        select_layers(STACK, spec)
    assert "10 layer(s) of ten" in str(info.value)
