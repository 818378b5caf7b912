"""Helpers shared by the post-processing tests."""

from __future__ import annotations

import bisect
import re
from collections import defaultdict
from pathlib import Path

__all__ = ["check_rewritten_part", "first_layers", "geos_targets", "laid_widths",
           "lines_not_kept"]

_C_WORD = re.compile(rb" C-?[0-9.]+")
_INSERTED = re.compile(rb"^(G92 E-?[0-9.]+|G1 C-?[0-9.]+|; printability.*)\r?\n?$")


def first_layers(path: Path, n: int, marker: bytes = b";LAYER_CHANGE") -> bytes:
    """The file up to (not including) its (n+1)-th layer marker: a valid, shorter G-code."""
    data = path.read_bytes()
    pos = -1
    for _ in range(n + 1):
        pos = data.find(b"\n" + marker, pos + 1)
        if pos < 0:
            return data
    return data[: pos + 1]


def lines_not_kept(old: bytes, new: bytes, may_change: set[int]) -> tuple[list[int], list[int]]:
    """Original lines (0-based) missing from the new file, in order, up to rotary words.

    Both files are normalised alike (lines of the kinds the tool inserts, ``G92 E…``,
    ``G1 C…`` and its comment block, are set aside; rotary words are removed), then the
    original lines are looked for in order: a line outside ``may_change`` must be found
    further on; a line in ``may_change`` (the part's extrusions) may be missing, and is
    only looked for within the next 64 lines so that it never jumps ahead to an identical
    line elsewhere.

    Returns
    -------
    (missing, changed)
        Lines outside ``may_change`` not found (must be empty), and lines of
        ``may_change`` not kept.
    """
    def norm(data: bytes) -> tuple[list[bytes], list[int]]:
        lines, where = [], []
        for i, ln in enumerate(data.splitlines(keepends=True)):
            if _INSERTED.match(ln):
                continue
            lines.append(_C_WORD.sub(b"", ln))
            where.append(i)
        return lines, where

    a, ia = norm(old)
    b, _ = norm(new)
    positions: dict[bytes, list[int]] = defaultdict(list)
    for j, ln in enumerate(b):
        positions[ln].append(j)
    ptr = 0
    missing: list[int] = []
    changed: list[int] = []
    for ln, i in zip(a, ia, strict=True):
        pos = positions.get(ln, [])
        k = bisect.bisect_left(pos, ptr)
        j = pos[k] if k < len(pos) else None
        if i in may_change:
            if j is not None and j < ptr + 64:
                ptr = j + 1
            else:
                changed.append(i)
        elif j is None:
            missing.append(i)
        else:
            ptr = j + 1
    return missing, changed


def geos_targets(g, filament_diameter: float = 1.75, quad_segs: int = 32, *,
                 interior: bool = True) -> list:
    """Per layer, G rebuilt by GEOS from the file's part beads (None: no bead): the
    independent reference the deposition checks measure against. ``interior`` as
    :class:`~printability.postprocess.PostprocessOptions` has it (default: the gaps inside
    the object filled, what the post-processor plans against by default)."""
    from printability.settings import Settings
    from printability.sources.gcode import layer_regions

    out: list = [None] * len(g.layers)
    for li, geom, _facts in layer_regions(g, settings=Settings(quad_segs=quad_segs),
                                          filament_diameter=filament_diameter,
                                          interior=interior):
        out[li] = geom if geom is not None and not geom.is_empty else None
    return out


def laid_widths(data: bytes, nozzle: str, monkeypatch) -> tuple[float, float]:
    """Post-process ``data`` for ``nozzle`` on T-T-R and measure what the plans lay:
    ``(kept, exact)``, the fraction of the part's extruded length kept, and of what is
    kept (with a planned width) the fraction laid within 5 µm of the slicer's planned
    width, or for an interior bead (inner walls, infill: it may lie wider where it fits)
    no narrower than 5 µm under it (the bead width of each move or piece at its
    orientation, from :meth:`Nozzle.bead_widths`, independent of the planner's own width
    table)."""
    import numpy as np

    import printability.postprocess as pp
    from printability.model.nozzle import parse_nozzle
    from printability.postprocess import pipeline

    plans = []
    real = pipeline.plan_orientations

    def spy(p0, p1, widths, *args, **kwargs):
        plan = real(p0, p1, widths, *args, **kwargs)
        inner = kwargs.get("interior")
        inner = np.zeros(len(p0), bool) if inner is None else np.asarray(inner, bool)
        plans.append((p0, p1, np.asarray(widths, float), inner, plan))
        return plan

    monkeypatch.setattr(pipeline, "plan_orientations", spy)
    pp.postprocess_bytes(data, options=pp.PostprocessOptions(nozzle=nozzle, machine="ttr"))
    nz = parse_nozzle(nozzle)
    total = kept = planned = exact = 0.0
    for p0, p1, widths, inner, plan in plans:
        d = p1 - p0
        length = np.hypot(d[:, 0], d[:, 1])
        direction = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
        whole = np.isfinite(plan.angle)
        move, t0, t1, angle = plan.piece_rows
        lens = np.concatenate([length[whole], length[move] * (t1 - t0)])
        laid = np.concatenate([nz.bead_widths(direction[whole], plan.angle[whole]),
                               nz.bead_widths(direction[move], angle)])
        plan_w = np.concatenate([widths[whole], widths[move]])
        wide_ok = np.concatenate([inner[whole], inner[move]])
        has = np.isfinite(plan_w)
        total += length.sum()
        kept += lens.sum()
        planned += lens[has].sum()
        err = laid[has] - plan_w[has]
        good = np.where(wide_ok[has], err >= -5e-3, np.abs(err) <= 5e-3)
        exact += lens[has][good].sum()
    return kept / total, exact / planned


def check_rewritten_part(old: bytes, new: bytes, g0, g1, nozzle: str) -> None:
    """What a post-processed slicer file must hold, from its text before (``old``, parsed
    ``g0``) and after (``new``, ``g1``): every slicer line outside the part's extrusions kept
    byte for byte and in order, some lines rewritten, rotary words present and never on an
    arc, and the deposition of ``nozzle`` never outside G beyond the tolerance on three
    layers spread over the part."""
    import numpy as np

    from gcode import NON_PART_CATEGORIES
    from printability.model.nozzle import parse_nozzle
    from printability.planning.check import check_deposition, extrusion_chords

    m = g0.moves
    part = m["is_extrusion"] & ~g0.moves_in(NON_PART_CATEGORIES)
    missing, changed = lines_not_kept(old, new, set(m["line"][part].tolist()))
    assert not missing, f"slicer lines lost or altered: {missing[:5]}"
    assert changed
    c = g1.words["line"][g1.words["letter"] == ord("C")]
    assert c.size > 0
    assert not np.isin(g1.lines["major"][c], [2, 3]).any()
    targets = geos_targets(g0)
    have = [i for i, t in enumerate(targets) if t is not None]
    layers = sorted({have[0], have[len(have) // 2], have[-1]})
    reports = check_deposition(extrusion_chords(g1), targets, parse_nozzle(nozzle),
                               layers=layers)
    assert reports and all(rep.max_outside <= 1e-3 + 2e-4 for rep in reports), reports
