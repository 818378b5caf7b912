"""The sampled joint space Ω of the sampled engine, and placing the nozzle at its samples.

Used by :mod:`printability.mmc.sampled` (which states what the samples and
their slack L prove) and its sweeps (:mod:`printability.mmc._sweeps`).

On ``xy`` and ``ttr`` machines the same code runs on the joints X, Y (a lattice
of spacing ``settings.resolution``, padded so every feasible position has its
nearest lattice point in it) and the nozzle angle (from :meth:`Machine.angles`),
so its results can be compared with the separable engines'.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from shapely.geometry.base import BaseGeometry

from printability.mmc.orifices import angle_gap, orifices_of
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

__all__ = ["SampleSpace", "placed", "ring_coords", "sample_space"]


@dataclass(frozen=True, eq=False)
class SampleSpace:
    """The sampled joint space Ω of a machine, and how far a sample is from any u.

    Attributes
    ----------
    names
        Joint names (``X``, ``Y``, ``C`` on separable machines).
    kinds
        ``prismatic``, ``revolute`` (about a joint axis away from the nozzle) or
        ``spin`` (the T-T-R rotary axis, about the nozzle origin).
    values
        Sampled values per joint (mm or degrees).
    wrap
        Whether the last value neighbours the first (full turn / symmetry period).
    steps
        Largest spacing between consecutive values, per joint.
    levers
        Largest displacement of a nozzle point per unit of the joint (1 for a
        prismatic joint; mm per degree for a rotation).
    reaches
        Largest distance from the joint's axis to a nozzle point, mm (0 if prismatic).
    slack
        L: every configuration of Ω has a sample whose footprint is within L mm
        (every nozzle point moves at most L), mm.
    pose
        ``u (k, p) -> (phi degrees, t (k, 2) mm)``.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    values: tuple[np.ndarray, ...]
    wrap: tuple[bool, ...]
    steps: tuple[float, ...]
    levers: tuple[float, ...]
    reaches: tuple[float, ...]
    slack: float
    pose: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.values)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) if self.values else 0

    def joint_vectors(self, flat: np.ndarray) -> np.ndarray:
        """Joint vectors (k, p) of flat sample indices (C order over :attr:`shape`)."""
        idx = np.unravel_index(flat, self.shape)
        return np.column_stack([v[i] for v, i in zip(self.values, idx, strict=True)])


def _lattice(lo: float, hi: float, h: float) -> np.ndarray:
    return np.arange(math.ceil(lo / h - 1e-9), math.floor(hi / h + 1e-9) + 1) * h


def sample_space(
    region: BaseGeometry, nozzle: Nozzle, machine: Machine, *, settings: Settings
) -> SampleSpace:
    """The joint-space sampling the sampled engine uses for this region and machine.

    Chains use their joints' values; ``xy``/``ttr`` use a lattice of spacing
    ``settings.resolution`` restricted to positions where the nozzle fits in the
    region's bounding box at some sampled angle, and the machine's angles.
    """
    if not machine.separable:  # a chain: its joints' values
        values, kinds, wrap, steps, levers, reaches = [], [], [], [], [], []
        joints = machine.joints
        for j, joint in enumerate(joints):
            vals = joint.values()
            span = joint.hi - joint.lo
            full = joint.kind == "revolute" and span >= 360.0 - 1e-9
            step = (360.0 / len(vals)) if full else (span / max(1, len(vals) - 1))
            if joint.kind == "revolute":
                reach = sum(math.hypot(*jj.offset) + (max(abs(jj.lo), abs(jj.hi))
                                                      if jj.kind == "prismatic" else 0.0)
                            for jj in joints[j + 1:])
                reach += math.hypot(*machine.tool_offset) + nozzle.radius
                lever = math.radians(1.0) * reach
            else:
                reach, lever = 0.0, 1.0
            values.append(np.asarray(vals, dtype=float))
            kinds.append(joint.kind)
            wrap.append(full and len(vals) > 2)
            steps.append(float(step))
            levers.append(lever)
            reaches.append(reach)
        slack = sum(lv * st / 2 for lv, st in zip(levers, steps, strict=True))
        return SampleSpace(tuple(j.name for j in joints), tuple(kinds), tuple(values),
                           tuple(wrap), tuple(steps), tuple(levers), tuple(reaches), slack,
                           machine.pose)

    h = float(settings.resolution)
    period = nozzle.symmetry_period
    angles = np.asarray(machine.angles(step=settings.angle_step, period=period), dtype=float)
    gap, wrap_a = angle_gap(machine, angles, period)
    turning = machine.turns(nozzle) and len(angles) > 1
    orifices = orifices_of(nozzle, quad_segs=settings.quad_segs)
    pts = np.concatenate([ring_coords(o.inner) for o in orifices])
    gminx, gminy, gmaxx, gmaxy = region.bounds
    lo = np.array([np.inf, np.inf])
    hi = np.array([-np.inf, -np.inf])
    for a in angles:
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        p = pts @ np.array([[c, s], [-s, c]])
        lo = np.minimum(lo, [gminx - p[:, 0].min(), gminy - p[:, 1].min()])
        hi = np.maximum(hi, [gmaxx - p[:, 0].max(), gmaxy - p[:, 1].max()])
    spin_lever = math.radians(1.0) * nozzle.radius
    slack = h / math.sqrt(2.0) + (spin_lever * gap / 2 if turning else 0.0)
    # positions where the nozzle fits the bounding box, padded so that the nearest sample
    # of every feasible configuration is in the grid (the optimistic pass needs it)
    pad = slack + h
    xs, ys = _lattice(lo[0] - pad, hi[0] + pad, h), _lattice(lo[1] - pad, hi[1] + pad, h)
    names, kinds = ("X", "Y"), ("prismatic", "prismatic")
    values: tuple[np.ndarray, ...] = (xs, ys)
    wraps, steps, levers, reaches = (False, False), (h, h), (1.0, 1.0), (0.0, 0.0)
    if machine.has_rotary:
        names += (machine.rotary_letter,)
        kinds += ("spin",)
        values += (angles,)
        wraps += (wrap_a,)
        steps += (gap,)
        levers += (spin_lever if turning else 0.0,)
        reaches += (nozzle.radius,)

    def pose(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.atleast_2d(u)
        phi = u[:, 2].copy() if u.shape[1] > 2 else np.zeros(len(u))
        return phi, u[:, :2].copy()

    return SampleSpace(names, kinds, values, wraps, steps, levers, reaches, slack, pose)


# --------------------------------------------------------------------------- placing


def placed(coords: np.ndarray, phi: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``coords`` (n, 2) in the nozzle frame placed at k poses → (k, n, 2)."""
    a = np.deg2rad(phi)[:, None]
    c, s = np.cos(a), np.sin(a)
    x = c * coords[None, :, 0] - s * coords[None, :, 1] + t[:, :1]
    y = s * coords[None, :, 0] + c * coords[None, :, 1] + t[:, 1:2]
    return np.stack([x, y], axis=-1)


def ring_coords(poly: BaseGeometry) -> np.ndarray:
    """Closed exterior ring coordinates of a polygon (n + 1, 2)."""
    return np.asarray(poly.exterior.coords)

