"""The split search's shortcuts change no answer (printability.planning._search.split_many).

The fused split tries a move's innermost interval first (where it fits nowhere, no interval
of the move fits) and starts a whole move's search after the candidates the move was
already refused at; the reference split tries every candidate of every group in order,
each through ``shapely.covers``. On real slicer files, call by call, both keep the same
pieces at the same orientations.
"""

from __future__ import annotations

import numpy as np
import pytest

import printability.planning.orientation as orientation
from printability.postprocess import PostprocessOptions, postprocess_bytes


@pytest.mark.parametrize("nozzle", ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25"])
@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_split_shortcuts_keep_the_exhaustive_pieces(request, monkeypatch, fixture, nozzle):
    data = request.getfixturevalue(fixture).read_bytes()
    split_many = orientation.split_many
    seen = {"calls": 0, "skipped": 0, "pieces": 0}

    def checked(*args, **kw):
        rows = split_many(*args, **kw)
        ref_rows = split_many(*args, **dict(kw, fast=False, tried=None))
        for got, want in zip(rows, ref_rows, strict=True):
            np.testing.assert_array_equal(got, want)
        seen["calls"] += 1
        seen["skipped"] += int(np.sum(kw["tried"])) if kw.get("tried") is not None else 0
        seen["pieces"] += len(rows[0])
        return rows

    monkeypatch.setattr(orientation, "split_many", checked)
    postprocess_bytes(data, options=PostprocessOptions(nozzle=nozzle, machine="ttr"))
    # the shortcuts were taken: moves were split, some after candidates already refused
    assert seen["calls"] > 0 and seen["pieces"] > 0 and seen["skipped"] > 0


def test_piece_map_reads_as_the_dict_of_lists_it_replaces():
    # moves 3 and 9 split, 5 dropped (no row); rows sorted by move, then as found
    rows = (np.array([3, 3, 9]), np.array([0.0, 0.6, 0.1]), np.array([0.4, 1.0, 0.9]),
            np.array([10.0, 190.0, -5.0]))
    pieces = orientation.PieceMap(np.array([9, 5, 3]), rows)
    eager = {9: [orientation.OrientedPiece(0.1, 0.9, -5.0)], 5: [],
             3: [orientation.OrientedPiece(0.0, 0.4, 10.0),
                 orientation.OrientedPiece(0.6, 1.0, 190.0)]}
    assert list(pieces) == [9, 5, 3] and len(pieces) == 3
    assert dict(pieces.items()) == eager and pieces == eager
    assert 5 in pieces and 4 not in pieces and pieces.get(4) is None
    assert pieces[3] is pieces[3]  # made once
    with pytest.raises(KeyError):
        pieces[4]
    with pytest.raises(TypeError):
        pieces[4] = []  # read-only
    plan = orientation.Plan(angle=np.zeros(10), width=np.zeros(10), pieces=pieces,
                            piece_rows=rows)
    assert (plan.split_moves, plan.dropped_moves) == (2, 1)
    np.testing.assert_array_equal(orientation.piece_rows_of(pieces)[0], rows[0])


@pytest.mark.parametrize("nozzle", ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25"])
def test_the_kept_middle_of_a_split_move_lays_the_planned_width(nozzle):
    # an L of two 0.45 mm beads: the first move ends in the corner, where the footprint
    # laying 0.45 mm pokes out ahead, so it is split; along its middle only the planned
    # width itself fits (the 10° grid's nearest orientations miss it by hundredths of a mm)
    from printability.model.machine import parse_machine
    from printability.model.nozzle import parse_nozzle
    from printability.planning.beadunion import bead_union

    w = 0.45
    p0 = np.array([[0.0, 0.0], [10.0, 0.0]])
    p1 = np.array([[10.0, 0.0], [10.0, 10.0]])
    target = bead_union(p0, p1, np.full(2, w / 2), grow=1e-3)
    noz, machine = parse_nozzle(nozzle), parse_machine("ttr")
    plan = orientation.plan_orientations(p0, p1, np.full(2, w), target, noz, machine,
                                         prepared_target=target)
    assert 0 in plan.pieces
    longest = max(plan.pieces[0], key=lambda p: p.t1 - p.t0)
    assert longest.t1 - longest.t0 > 0.9
    # the planned width itself, never wider (the grid's nearest miss by 0.015 mm or more)
    assert w - 1e-9 <= noz.bead_width(0.0, longest.angle) <= w + 1e-12


def test_what_fits_nowhere_at_twice_the_split_length_is_halved():
    # an L of two 0.5 mm legs of 0.45 mm beads: cut in thirds (pieces of at most twice the
    # 0.8 x 0.3 ellipse's split length, 0.1 mm), no piece of either leg fits anywhere, so
    # both were dropped whole; halved, one piece of each fits (and so it does in the
    # reference split, shapely's covers on every candidate)
    from printability.model.machine import parse_machine
    from printability.model.nozzle import parse_nozzle
    from printability.planning.beadunion import bead_union

    w, leg = 0.45, 0.5
    p0 = np.array([[0.0, 0.0], [leg, 0.0]])
    p1 = np.array([[leg, 0.0], [leg, leg]])
    target = bead_union(p0, p1, np.full(2, w / 2), grow=1e-3)
    noz, machine = parse_nozzle("ellipse:major=0.8,minor=0.3"), parse_machine("ttr")
    plan = orientation.plan_orientations(p0, p1, np.full(2, w), target, noz, machine,
                                         prepared_target=target)
    step = noz.radius / 4
    for move in (0, 1):
        kept = plan.pieces[move]
        assert kept and all((p.t1 - p.t0) * leg <= step * 1.000001 for p in kept)
    ctx = orientation.plan_context(p0, p1, np.full(2, w), target, noz, machine,
                                   prepared_target=target)
    rows = orientation.split_many(ctx, np.zeros(2),
                                  orientation.candidate_orientations(machine, noz, step=10.0),
                                  fast=False)
    assert set(rows[0].tolist()) == {0, 1}
