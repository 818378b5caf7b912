"""The split search's shortcuts change no answer (printability.motion.orientation._split_many).

The fused split tries a move's innermost interval first (where it fits nowhere, no interval
of the move fits) and starts a whole move's search after the candidates the move was
already refused at; the reference split tries every candidate of every group in order,
each through ``shapely.covers``. On real slicer files, call by call, both keep the same
pieces at the same orientations.
"""

from __future__ import annotations

import numpy as np
import pytest

import printability.motion.orientation as orientation
from printability.postprocess import PostprocessOptions, postprocess_bytes


@pytest.mark.parametrize("nozzle", ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25"])
@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_split_shortcuts_keep_the_exhaustive_pieces(request, monkeypatch, fixture, nozzle):
    data = request.getfixturevalue(fixture).read_bytes()
    split_many = orientation._split_many
    seen = {"calls": 0, "skipped": 0, "pieces": 0}

    def checked(*args, **kw):
        out, rows = split_many(*args, **kw)
        ref = dict(kw, fast=False, tried=None)
        _, ref_rows = split_many(*args, **ref)
        for got, want in zip(rows, ref_rows, strict=True):
            np.testing.assert_array_equal(got, want)
        seen["calls"] += 1
        seen["skipped"] += int(np.sum(kw["tried"])) if kw.get("tried") is not None else 0
        seen["pieces"] += len(rows[0])
        return out, rows

    monkeypatch.setattr(orientation, "_split_many", checked)
    postprocess_bytes(data, options=PostprocessOptions(nozzle=nozzle, machine="ttr"))
    # the shortcuts were taken: moves were split, some after candidates already refused
    assert seen["calls"] > 0 and seen["pieces"] > 0 and seen["skipped"] > 0
