"""Sampled MMC engine: any machine chain, by sampling Ω and testing containment.

Machines whose translations depend on their rotations (a polar printer, a SCARA
arm) are not separable: there is no erosion per angle to compute. This engine
samples the joint space Ω on the product grid of the joints' own steps
(:meth:`Machine.joint_grid`), places the nozzle at every sample with
:meth:`Machine.pose` and tests **A^u ⊆ G directly**:

* P = the feasible samples. For a connected orifice, A^u lies in the interior of
  G exactly when one of its points is inside G (``shapely.contains_xy``) and no
  edge of ∂G meets it. A numba kernel (:mod:`printability.mmc._containment`) tests
  the edges of ∂G near the placed orifice (bucketed) against the *true* shape in
  the orifice's frame: an ellipse or circle (the edge mapped to the unit disk
  comes within distance 1 of its centre), a rectangle (Liang–Barsky clipping) or
  a polygon (edge crossings, or an edge end inside). Touching ∂G counts as leaving
  G (P = C \\ B), with a 1e-9 relative margin for tangencies blurred by rounding.
  Never a configuration that puts material outside G; every orifice of a head
  must pass.
* S = the union of the footprints swept between consecutive feasible samples
  along each joint (on the XY/T-T-R lattice along X only), each hull checked
  inside G before it is kept; samples left uncovered add their own footprint.
  So S ⊆ G always. A kept revolute hull sticks out of the true arc sweep by at
  most e (within ``settings.chord_tolerance`` where possible). How the hulls
  are built, bounded (e, and the sagitta s they may miss) and checked:
  :mod:`printability.mmc._sweeps`.
* Bounds. Every configuration u of Ω is within half a step of a sample in each
  joint, so each nozzle point is within L = Σ_j lever_j·step_j/2 of where it is at
  that sample (lever: 1 for a prismatic joint, the largest distance from the axis
  to the nozzle, per radian, for a revolute one; on XY/T-T-R L = h/√2 + r_max·Δφ/2).
  A feasible u therefore has a sample whose orifices shrunk by L fit in G (an
  ellipse E(a, b) is shrunk to E(ka, kb), k = 1 − L/b, which lies inside its
  erosion), so S ⊆ S_outer = ∪ over those samples of A^u ⊕ D(L), and
  ``lost_area_bounds = (λ(G) − λ(S_outer ∩ G), λ(G) − λ(S) + 2e·perimeter(S))``.
  When L exceeds an orifice's inscribed radius the lower bound is 0 (a note says
  so), unless no sample brings the nozzle near G at all.

On ``xy`` and ``ttr`` machines the same code runs on the joints X, Y and the
nozzle angle (:mod:`printability.mmc._sample_space`), so its results can be
compared with the separable engines'.

Components of P are the connected components of the feasible samples in the
joint grid (``scipy.ndimage.label``, face neighbours; full-turn revolute joints
and T-T-R angles covering a whole symmetry period wrap).

Cost: one pose, one point-in-G test and a few edge tests per sample (chunks of
2¹⁸; values of the first joint whose second joint axis cannot bring the nozzle
to G's bounding box are skipped), then a union of O(#runs) hulls. The number of
samples, the product of the joints' value counts, and the memory are estimated
up front and refused above ``max_samples`` or ``settings.max_memory`` with a
ResourceError that suggests coarser steps.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import MultiPolygon
from shapely.geometry.base import BaseGeometry

from printability.errors import ResourceError
from printability.mmc._containment import (
    ContainmentTest,
    Edges,
    boundary_edges,
    containment_test,
    run_containment_test,
)
from printability.mmc._sample_space import SampleSpace, placed, ring_coords, sample_space
from printability.mmc._sweeps import sweep
from printability.mmc.orifices import Orifice, grid_rectangles, orifices_of
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = ["DEFAULT_MAX_SAMPLES", "SampleSpace", "mmc_sampled", "sample_space"]

DEFAULT_MAX_SAMPLES = 60_000_000
"""Default largest number of joint-space samples the sampled engine accepts."""

_CHUNK = 1 << 18
_MAX_COMPONENT_POINTS = 200_000


# --------------------------------------------------------------------------- components


def _components(space: SampleSpace, feasible: np.ndarray) -> tuple[int, np.ndarray]:
    """Label the connected components of the feasible samples (face neighbours, wraps)."""
    if not feasible.any():
        return 0, np.zeros(feasible.shape, dtype=np.int32)
    structure = ndimage.generate_binary_structure(feasible.ndim, 1)
    labels, count = ndimage.label(feasible, structure=structure)
    parent = list(range(count + 1))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for j, wraps in enumerate(space.wrap):
        if not wraps:
            continue
        first = np.take(labels, 0, axis=j)
        last = np.take(labels, -1, axis=j)
        both = (first > 0) & (last > 0)
        for p, q in set(zip(first[both].tolist(), last[both].tolist(), strict=True)):
            rp, rq = find(p), find(q)
            if rp != rq:
                parent[max(rp, rq)] = min(rp, rq)
    roots = np.array([find(x) for x in range(count + 1)])
    merged = roots[labels]
    # renumber 0..n-1 in order of first appearance (flat C order); background -1
    flat = merged.ravel()
    nz = flat[flat > 0]
    _, first_idx = np.unique(nz, return_index=True)
    order = np.unique(nz)[np.argsort(first_idx)]
    remap = np.full(count + 1, -1, dtype=np.int32)
    remap[order] = np.arange(len(order), dtype=np.int32)
    return len(order), remap[merged]


# --------------------------------------------------------------------------- engine


def _draw_quad_segs(orifices: tuple[Orifice, ...], tolerance: float, most: int) -> int:
    """Fewest vertices per quarter keeping curved orifices' polygons within ``tolerance``.

    The polygons of a sweep cost union time in proportion to their vertices; the
    inner polygon of a curve of largest semi-axis a with n vertices is within
    a·(1 − cos(π/n)) of it, the outer within a·(1/cos(π/n) − 1).
    """
    a = max([max(o.semi_axes) for o in orifices if o.shape.conic] or [0.0])
    if a <= 0:
        return most
    x = math.acos(1.0 / (1.0 + min(tolerance / a, 0.5)))
    return int(min(most, max(2, math.ceil(math.pi / x / 4))))



def _empty_result(g, nozzle, machine, space, notes, t0, resolution, angle_step):
    return MMCResult(
        engine="sampled", nozzle=nozzle, machine=machine, target=g, as_built=MultiPolygon(),
        target_area=float(g.area), as_built_area=0.0, lost_area=float(g.area),
        lost_area_bounds=(float(g.area), float(g.area)),
        motion=MotionRestriction(angles=np.zeros(0),
                                 samples=np.zeros((0, len(space.values)))),
        components=Components(count=0, geometries=(), angle_ranges=()),
        resolution=resolution, angle_step=angle_step, elapsed=time.perf_counter() - t0,
        notes=tuple(notes), extra={"samples": space.size,
                                   "feasible": np.zeros(space.shape, dtype=bool),
                                   "joint_names": space.names, "joint_values": space.values,
                                   "slack": space.slack})


def _chunks(space: SampleSpace, machine: Machine, nozzle: Nozzle, g: BaseGeometry):
    """Flat sample indices to test, in chunks, skipping first-joint values out of reach.

    For a chain, the axis of the second joint moves with the first one only; a value
    of the first joint whose second axis is farther from G's bounding box than the
    rest of the chain can reach (offsets, prismatic travels, tool, nozzle) cannot put
    the nozzle in G, whatever the other joints do.
    """
    n = space.size
    keep = np.ones(space.shape[0], dtype=bool)
    if not machine.separable and len(machine.joints) >= 2:
        joints = machine.joints
        head = replace(machine, joints=joints[:1], tool_offset=joints[1].offset,
                       tool_angle=0.0)
        _, centre = head.pose(space.values[0][:, None])
        rest = sum(math.hypot(*jj.offset) for jj in joints[2:])
        rest += sum(max(abs(jj.lo), abs(jj.hi)) for jj in joints[1:] if jj.kind == "prismatic")
        rest += math.hypot(*machine.tool_offset) + nozzle.radius
        # plus how far the axis moves within half a step of the first joint, so that
        # configurations between the skipped samples cannot reach G either
        rest += space.levers[0] * space.steps[0] / 2 + space.slack
        minx, miny, maxx, maxy = g.bounds
        dx = np.maximum(np.maximum(minx - centre[:, 0], centre[:, 0] - maxx), 0.0)
        dy = np.maximum(np.maximum(miny - centre[:, 1], centre[:, 1] - maxy), 0.0)
        keep = np.hypot(dx, dy) <= rest * (1 + 1e-9) + 1e-9
    block = n // space.shape[0]
    starts = np.flatnonzero(keep) * block
    if len(starts) == 0:
        return
    # merge consecutive kept blocks into ranges, then cut the ranges into chunks
    breaks = np.flatnonzero(np.diff(starts) != block) + 1
    for group in np.split(starts, breaks):
        lo, hi = int(group[0]), int(group[-1]) + block
        for c in range(lo, hi, _CHUNK):
            yield np.arange(c, min(hi, c + _CHUNK))


def mmc_sampled(
    region: BaseGeometry,
    nozzle: Nozzle,
    machine: Machine,
    *,
    settings: Settings = DEFAULT_SETTINGS,
    max_samples: int = DEFAULT_MAX_SAMPLES,
) -> MMCResult:
    """MMC of any machine by sampling its joint space and testing containment.

    Parameters
    ----------
    region
        G, a validated MultiPolygon, mm.
    nozzle
        The nozzle (every orifice must fit).
    machine
        Any machine: a chain (joints sampled at their own steps), or ``xy``/``ttr``
        (positions on a lattice of spacing ``settings.resolution``, angles from the
        machine's step or ``settings.angle_step``).
    settings
        ``chord_tolerance`` bounds the hull-versus-arc deviation of revolute sweeps;
        ``quad_segs`` sets the polygons of curved orifices; ``max_memory`` limits
        the working set.
    max_samples
        Refuse (ResourceError) above this many joint-space samples.

    Returns
    -------
    MMCResult
        ``motion.samples``: the feasible joint vectors (k, p); ``as_built``: S ⊆ G;
        ``extra["feasible"]``: the boolean feasibility grid over the joint values
        ``extra["joint_values"]``.

    Raises
    ------
    ResourceError
        Too many samples for ``max_samples`` or the memory limit.

    Notes
    -----
    See the module docstring for what S approximates and how the bounds are built.
    """
    t0 = time.perf_counter()
    g = region
    space = sample_space(g, nozzle, machine, settings=settings)
    orifices = orifices_of(nozzle, quad_segs=settings.quad_segs)
    n = space.size
    is_chain = not machine.separable
    resolution = space.slack if is_chain else float(settings.resolution)
    rot_steps = [s for s, k in zip(space.steps, space.kinds, strict=True) if k != "prismatic"]
    angle_step = max(rot_steps) if rot_steps and (is_chain or space.levers[-1] > 0) else 0.0
    describe = _check_size(space, machine, len(orifices), settings, max_samples)
    notes: list[str] = []
    if n == 0:
        notes.append("the nozzle does not fit in the region's bounding box at any sampled "
                     "angle: nothing can be printed")
        return _empty_result(g, nozzle, machine, space, notes, t0, resolution, angle_step)

    shapely.prepare(g)
    slack = space.slack
    tests = _containment_tests(g, orifices, slack, notes)
    tested = _test_samples(space, machine, nozzle, g, orifices, tests)
    feasible, optimistic = tested.feasible, tested.optimistic
    n_feasible = int(feasible.sum())
    if tested.over_part == 0:
        notes.append(f"no configuration of machine {machine.name!r} puts the nozzle over the "
                     "part: it is out of the machine's reach")

    # ---- S: sweeps along every joint of a chain; on the xy/ttr lattice, whose step is
    # far below the nozzle size, along X only (neighbouring rows overlap; what is left
    # between their ends is a scallop of depth ~h²/(8r), and the bounds account for it)
    tol = float(settings.chord_tolerance)
    axes = [j for j, k in enumerate(space.kinds) if k != "spin"] if is_chain else [0]
    draw = orifices_of(nozzle, quad_segs=_draw_quad_segs(orifices, tol, settings.quad_segs))
    as_built, excess = _swept(space, feasible, draw, orifices, nozzle, g, tol, axes)
    target_area = float(g.area)
    as_built_area = float(as_built.area)
    lost = max(0.0, target_area - as_built_area)
    hi = min(target_area, lost + 2 * excess * float(as_built.length))
    if tests.has_outer and optimistic.any():
        outer = _outer_bound(space, optimistic, draw, nozzle, g, tol, axes)
        lo_b = max(0.0, target_area - float(shapely.intersection(outer, g).area))
    elif tests.has_outer or tested.near == 0:
        lo_b = target_area
    else:
        lo_b = 0.0
    lo_b = min(lo_b, lost)

    samples, angles, components, labels = _motion(space, feasible, is_chain,
                                                  float(settings.resolution))
    steps = ", ".join(f"{nm} every {st:g}" for nm, st in
                      zip(space.names, space.steps, strict=True))
    notes.insert(0, (
        f"sampled: {n:,} configurations ({describe}; {steps}), {n_feasible:,} feasible; every "
        f"configuration is within {slack:.3g} mm (any nozzle point) of a sample; S sweeps "
        f"hulls between consecutive feasible samples (revolute sweeps within {excess:.2g} mm "
        "of the true arcs)"
    ))
    return MMCResult(
        engine="sampled",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=as_built,
        target_area=target_area,
        as_built_area=as_built_area,
        lost_area=lost,
        lost_area_bounds=(lo_b, hi),
        motion=MotionRestriction(angles=np.asarray(angles, dtype=float), samples=samples),
        components=components,
        resolution=resolution,
        angle_step=angle_step,
        elapsed=time.perf_counter() - t0,
        notes=tuple(notes),
        extra={"samples": n, "feasible": feasible, "optimistic": int(optimistic.sum()),
               "joint_names": space.names, "joint_values": space.values, "slack": slack,
               "sweep_excess": excess, "component_labels": labels},
    )


# --------------------------------------------------------------------------- stages


def _check_size(space: SampleSpace, machine: Machine, n_orifices: int, settings: Settings,
                max_samples: int) -> str:
    """The joints' value counts, as words; ResourceError above the sample or memory limit."""
    n = space.size
    p = len(space.values)
    describe = ", ".join(f"{nm}: {len(v):,} values" for nm, v in
                         zip(space.names, space.values, strict=True))
    memory = n * (2 + 4 + 8 * p) + _CHUNK * (16 * p + 64 * n_orifices + 64)
    if n > max_samples or memory > settings.max_memory:
        raise ResourceError(
            f"the sampled engine would test {n:,} configurations of machine {machine.name!r} "
            f"({describe}) needing about {memory / 2**20:,.0f} MiB; the limits are "
            f"{max_samples:,} configurations and {settings.max_memory / 2**20:,.0f} MiB: use "
            "coarser joint steps in the machine profile (or a coarser resolution / angle "
            "step on xy and ttr machines), or narrow the joint ranges to the part"
        )
    return describe


@dataclass(frozen=True, eq=False)
class _Tests:
    """The containment tests: ∂G's bucketed edges, the feasibility test of every orifice
    and, when ``has_outer``, the optimistic one (the orifice shrunk by the slack)."""

    edges: Edges
    feasible: list[ContainmentTest]
    optimistic: list[ContainmentTest]
    has_outer: bool


def _containment_tests(g: BaseGeometry, orifices: tuple[Orifice, ...], slack: float,
                       notes: list[str]) -> _Tests:
    """The tests of every orifice; a note in ``notes`` when there is no lower bound."""
    reach_max = max(o.circumradius + math.hypot(*o.center) for o in orifices)
    edges = boundary_edges(g, max(reach_max / 2, 1e-3))
    feasible_tests = [containment_test(o, 0.0, closed=True) for o in orifices]
    r_in_min = min(o.inradius for o in orifices)
    has_outer = slack * 1.01 < r_in_min
    opt_tests = [containment_test(o, slack, closed=False) for o in orifices] if has_outer else []
    if has_outer and any(tt.empty for tt in opt_tests):
        has_outer = False
    if not has_outer:
        notes.append(
            f"a configuration can be {slack:.3g} mm (every nozzle point) away from the nearest "
            f"sample, more than the nozzle's inscribed radius {r_in_min:.3g} mm: no lower "
            "bound on the lost area (reported as 0); use finer joint steps"
        )
    return _Tests(edges, feasible_tests, opt_tests, has_outer)


@dataclass(frozen=True, eq=False)
class _Tested:
    """The samples' verdicts on the joint grid (feasible, optimistic), how many put the
    first orifice's centre over G, and how many bring the nozzle (grown by the slack)
    to G's bounding box."""

    feasible: np.ndarray
    optimistic: np.ndarray
    over_part: int
    near: int


def _test_samples(space: SampleSpace, machine: Machine, nozzle: Nozzle, g: BaseGeometry,
                  orifices: tuple[Orifice, ...], tests: _Tests) -> _Tested:
    """Every sample tested, chunk by chunk: every orifice must pass."""
    n = space.size
    feasible = np.zeros(n, dtype=bool)
    optimistic = np.zeros(n, dtype=bool)
    over_part = 0  # samples with the first orifice's centre over G
    # samples whose nozzle, grown by the slack, reaches G's bounding box: with none, no
    # configuration at all (sampled or not) can print anything
    near = 0
    minx, miny, maxx, maxy = g.bounds
    margin = nozzle.radius + space.slack
    edges = tests.edges
    for flat in _chunks(space, machine, nozzle, g):
        phi, t = space.pose(space.joint_vectors(flat))
        near += int(np.count_nonzero((t[:, 0] >= minx - margin) & (t[:, 0] <= maxx + margin)
                                     & (t[:, 1] >= miny - margin) & (t[:, 1] <= maxy + margin)))
        ok = np.ones(len(flat), dtype=bool)
        for k, (test, o) in enumerate(zip(tests.feasible, orifices, strict=True)):
            res, n_over = run_containment_test(test, o.center, g, edges, phi, t, ok)
            ok &= res
            over_part += n_over if k == 0 else 0
        feasible[flat] = ok
        if tests.has_outer:
            oo = np.ones(len(flat), dtype=bool)
            for test, o in zip(tests.optimistic, orifices, strict=True):
                oo &= run_containment_test(test, o.center, g, edges, phi, t, oo)[0]
            optimistic[flat] = oo | ok
    return _Tested(feasible.reshape(space.shape), optimistic.reshape(space.shape), over_part,
                   near)


def _swept(space: SampleSpace, feasible: np.ndarray, draw: tuple[Orifice, ...],
           orifices: tuple[Orifice, ...], nozzle: Nozzle, g: BaseGeometry, tol: float,
           axes: list[int]) -> tuple[BaseGeometry, float]:
    """S ⊆ G: the checked sweeps along ``axes``, plus the footprints of the samples no kept
    sweep covers; and the largest excess e of a kept revolute hull, mm."""
    polys, excess, covered = sweep(space, feasible, draw, orifices, nozzle.radius, g,
                                   tolerance=tol, axes=axes, verify=True)
    lonely = np.flatnonzero((feasible & ~covered).ravel())
    if len(lonely):
        phi, t = space.pose(space.joint_vectors(lonely))
        for o in draw:
            for piece in o.inner_pieces:
                polys.extend(shapely.polygons(placed(ring_coords(piece), phi, t)).tolist())
    return (shapely.union_all(polys) if polys else MultiPolygon()), excess


def _outer_bound(space: SampleSpace, optimistic: np.ndarray, draw: tuple[Orifice, ...],
                 nozzle: Nozzle, g: BaseGeometry, tol: float, axes: list[int]) -> BaseGeometry:
    """S_outer ⊇ S: the optimistic samples' footprints grown by the slack, swept."""
    # one joint suffices to cover every optimistic sample: prefer a prismatic one
    order = sorted(axes, key=lambda j: (space.kinds[j] != "prismatic", -space.shape[j]))
    axis = order[0] if order else 0
    o_polys, _, _ = sweep(space, optimistic, draw, draw, nozzle.radius, g,
                          tolerance=tol, axes=[axis], verify=False, grow=space.slack)
    return shapely.union_all(o_polys)


def _motion(space: SampleSpace, feasible: np.ndarray, is_chain: bool,
            resolution: float) -> tuple[np.ndarray, np.ndarray, Components, np.ndarray]:
    """P: the feasible joint vectors, the angles they use, their components and labels."""
    p = len(space.values)
    n_feasible = int(feasible.sum())
    samples_flat = np.flatnonzero(feasible.ravel())
    samples = space.joint_vectors(samples_flat) if len(samples_flat) else np.zeros((0, p))
    phi_f, t_f = space.pose(samples) if len(samples) else (np.zeros(0), np.zeros((0, 2)))
    count, labels = _components(space, feasible)
    lab_f = labels.ravel()[samples_flat]
    geoms: list[BaseGeometry] = []
    ranges: list[tuple[float, float]] = []
    for c_id in range(count):
        sel = lab_f == c_id
        ranges.append((float(phi_f[sel].min()), float(phi_f[sel].max())))
        if is_chain:
            if n_feasible <= _MAX_COMPONENT_POINTS:
                geoms.append(shapely.multipoints(t_f[sel]))
        else:
            # the lattice cells of its positions (any angle), merged into rectangles
            mask = labels == c_id
            if mask.ndim == 3:
                mask = mask.any(axis=2)
            rects = grid_rectangles(mask.T, space.values[0], space.values[1], resolution)
            geoms.append(shapely.union_all(shapely.box(*rects.T)))
    components = Components(
        count=count,
        geometries=tuple(geoms) if len(geoms) == count else None,
        angle_ranges=tuple(ranges),
    )
    if is_chain:
        angles = np.unique(np.round(np.mod(phi_f, 360.0), 9))
    else:
        angles = space.values[2] if p > 2 else np.array([0.0])
    return samples, angles, components, labels
