"""Turns around the pieces of split moves made while moving (issue 22).

A move no single orientation prints whole is cut into pieces, each at its own
orientation. The turn into a piece (from the piece before it, or from the previous move
for its first piece), and from the last piece into the next whole move, is made during
the piece when the footprint turning along it fits (``Plan.piece_fold``, the same test
as the whole moves' ``Plan.fold``), and a turn on the way to a piece's start, over the
dropped stretch before it, rides on that line: nothing is deposited there. What remains
a rotation-only line is a turn too large, or one that does not fit while moving.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pp_helpers import geos_targets

import printability.planning.orientation as orientation
import printability.postprocess._rewrite_kernel as rk
import printability.postprocess.pipeline as pipeline
from gcode import parse_gcode
from printability.model.nozzle import parse_nozzle
from printability.planning import footprints as fp
from printability.planning.check import check_deposition, extrusion_chords
from printability.planning.turns import turning_fits
from printability.postprocess import PostprocessOptions, postprocess_bytes

HERE = Path(__file__).parent
PART = HERE / "data" / "flavor_part.gcode"
ELLIPSE = "ellipse:major=0.8,minor=0.3"
TOL = 1e-3


def _rotation_only(text: bytes) -> int:
    return sum(1 for ln in text.splitlines() if ln.startswith(b"G1 C"))


def _run(**kw) -> bytes:
    new, _ = postprocess_bytes(PART.read_bytes(), options=PostprocessOptions(
        nozzle=ELLIPSE, machine="ttr-klipper", **kw))
    return new


def test_piece_turns_ride_on_the_moves_and_stay_inside(monkeypatch):
    new = _run()
    with monkeypatch.context() as mp:
        plan = orientation.plan_orientations
        mp.setattr(pipeline, "plan_orientations",
                   lambda *a, **k: plan(*a, **{**k, "options": dataclasses.replace(
                       k["options"], fold_pieces=False)}))
        without = _run()
    assert _rotation_only(new) < _rotation_only(without)
    # a C word on a new extruding line of a split move, and on a line to a piece's start
    lines = [ln.split(b";")[0].split() for ln in new.splitlines()]
    moving = [w for w in lines if w[:1] == [b"G1"] and any(x[:1] == b"E" for x in w)
              and any(x[:1] == b"C" for x in w)]
    assert moving
    g0 = parse_gcode(PART.read_bytes())
    targets = geos_targets(g0)
    layers = [i for i, t in enumerate(targets) if t is not None]
    reports = check_deposition(extrusion_chords(parse_gcode(new)), targets, parse_nozzle(ELLIPSE),
                               layers=layers)
    assert reports
    for r in reports:
        assert r.max_outside <= TOL + 2e-4, f"layer {r.layer}: {r.max_outside} mm outside"


def test_the_compiled_rewrite_writes_the_reference_with_piece_folds(monkeypatch):
    statuses = []
    kernel = rk.rewrite_kernel

    def spy(*a):
        r = kernel(*a)
        statuses.append(int(r[0]))
        return r

    with monkeypatch.context() as mp:
        mp.setattr(rk, "rewrite_kernel", spy)
        new = _run()
    assert statuses == [rk.OK]
    with monkeypatch.context() as mp:
        mp.setattr(rk, "rewrite_compiled", lambda *a: None)  # the reference writes it all
        ref = _run()
    assert new == ref


def test_piece_folds_are_the_turning_footprint_test(monkeypatch):
    """Every piece fold of the plans is a turn of at most ``fold_max`` whose turning
    footprint fits; the test in steps accepts whatever the one-step bound accepts."""
    seen = []
    plan_of = orientation.plan_orientations

    def record(p0, p1, widths, target, nozzle, machine, **kw):
        plan = plan_of(p0, p1, widths, target, nozzle, machine, **kw)
        seen.append((p0, p1, nozzle, kw, plan))
        return plan

    monkeypatch.setattr(pipeline, "plan_orientations", record)
    _run()
    fold_max = orientation.OrientationOptions().fold_max
    folds = 0
    for p0, p1, nozzle, kw, plan in seen:
        assert plan.piece_fold is not None and len(plan.piece_fold) == len(plan.piece_rows[0])
        pm, t0, t1, pa = plan.piece_rows
        pieces = fp.convex_pieces(nozzle)
        grown = kw["prepared_target"]
        per = nozzle.symmetry_period
        for r in np.flatnonzero(plan.piece_fold):
            m = pm[r]
            if r > 0 and pm[r - 1] == m:
                prev = pa[r - 1]
            else:
                assert kw["chained"][m]
                prev = plan.angle[m - 1] if np.isfinite(plan.angle[m - 1]) else pa[r - 1]
                assert np.isfinite(plan.angle[m - 1]) or pm[r - 1] == m - 1
            end = pa[r] + per * np.round((prev - pa[r]) / per)
            assert 0 < abs(end - prev) <= fold_max
            d = p1[m] - p0[m]
            a, b = p0[m] + t0[r] * d, p0[m] + t1[r] * d
            assert turning_fits(grown, pieces, a[None], b[None],
                                             np.array([prev]), np.array([end]))[0]
            folds += 1
        # the steps refine the one-step bound: what the bound accepts, the steps accept too
        rng = np.random.default_rng(0)
        i = rng.integers(0, len(p0), 300)
        phi0 = rng.uniform(0, 180, 300)
        phi1 = phi0 + rng.uniform(-20, 20, 300)
        one = fp.fits(grown, pieces, p0[i], p1[i], phi0, angle_end=phi1)
        steps = turning_fits(grown, pieces, p0[i], p1[i], phi0, phi1)
        assert one.any() and np.all(steps[one])
    assert folds > 0
