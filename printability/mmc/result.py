"""Result types shared by every MMC engine.

All engines return the same immutable :class:`MMCResult`, so the ranking, the
report, the G-code side and the tests never care which engine ran.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from shapely.geometry.base import BaseGeometry

from printability.model.geometry import Grid, Raster
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle

__all__ = ["Components", "MMCInternalError", "MMCResult", "MotionRestriction", "PackedMasks"]


class MMCInternalError(RuntimeError):
    """An engine produced a result that contradicts its own guarantees: a bug, not a user error.

    Deliberately not a :class:`printability.errors.PrintabilityError`: the CLI
    keeps the traceback of anything else, which is what a bug report needs.
    Raised instead of reporting nonsense (a lost area above the part's area,
    bounds that do not contain the estimate, an empty motion region where the
    nozzle certainly fits).
    """


@dataclass(frozen=True, eq=False)
class PackedMasks:
    """A stack of boolean masks on one Grid, one per sampled angle, stored compactly.

    Bits are packed 64 pixels to a ``uint64`` word along each row: pixel
    ``[i, j]`` is bit ``j % 64`` (least significant first) of word
    ``[i, j // 64]``; bits past ``grid.nx`` are 0. All angles share ``base``
    except at the words listed in ``words`` (flat indices into ``base``),
    whose value at angle k is ``values[k, b]``. The raster engine lists there
    the words near ∂G where the masks differ between angles, so 180 angles of
    a 2500² layer take tens of MB instead of 1.1 GB of booleans.

    Attributes
    ----------
    grid
        The grid of every mask.
    base
        ``uint64 (ny, ceil(nx / 64))``: the words common to all angles.
    words
        ``int64 (m,)``: flat indices of the words that vary with the angle.
    values
        ``uint64 (k, m)``: their value at each angle.
    """

    grid: Grid
    base: np.ndarray
    words: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.values.shape[0])

    @property
    def nbytes(self) -> int:
        """Memory held, bytes."""
        return int(self.base.nbytes + self.words.nbytes + self.values.nbytes)

    def bits(self, k: int) -> np.ndarray:
        """The packed words of mask ``k`` (a new ``uint64 (ny, nw)`` array)."""
        out = self.base.copy()
        out.reshape(-1)[self.words] = self.values[k]
        return out

    def _unpack(self, bits: np.ndarray) -> np.ndarray:
        b8 = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)
        return np.unpackbits(b8, axis=-1, bitorder="little", count=self.grid.nx).astype(bool)

    def mask(self, k: int) -> Raster:
        """Mask ``k`` as a boolean Raster (``(ny, nx)``)."""
        if not -len(self) <= k < len(self):
            raise IndexError(f"mask index {k} out of range for {len(self)} angles")
        return Raster(self.grid, self._unpack(self.bits(k)))

    def any(self) -> Raster:
        """Union over the angles, as a boolean Raster."""
        out = self.base.copy()
        flat = out.reshape(-1)
        flat[self.words] = np.bitwise_or.reduce(self.values, axis=0) if len(self) else 0
        return Raster(self.grid, self._unpack(out))

    def contains(self, k: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether mask ``k`` holds the pixels containing points (x, y) (mm); False off-grid."""
        g = self.grid
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        j = np.floor((x - g.x0) / g.h).astype(np.int64)
        i = np.floor((y - g.y0) / g.h).astype(np.int64)
        ok = (i >= 0) & (i < g.ny) & (j >= 0) & (j < g.nx)
        bits = self.bits(k)
        out = np.zeros(np.broadcast(x, y).shape, bool)
        ii, jj = i[ok], j[ok]
        words = bits[ii, jj >> 6]
        out[ok] = ((words >> (jj & 63).astype(np.uint64)) & np.uint64(1)).astype(bool)
        return out


@dataclass(frozen=True, eq=False)
class MotionRestriction:
    """The motion restriction P = C \\ B of a separable machine, per sampled angle.

    Exactly one of ``regions`` (vector engines: P_φ as shapely geometry, one
    per angle) and ``masks`` (raster engine: a boolean Raster of shape
    ``(len(angles), ny, nx)``; a pixel is True when its *centre* is a
    feasible position, conservatively) is set. For chains (sampled engine)
    ``samples`` holds the feasible joint vectors instead.

    Attributes
    ----------
    angles
        The sampled nozzle angles, degrees (``[0.0]`` on XY).
    regions
        P_φ per angle (vector engines).
    masks
        P_φ per angle (raster engine), inner approximation: every True pixel
        centre is a configuration that keeps the whole nozzle inside G.
    count
        For rasters: how many sampled angles fit at each pixel (uint16 Raster).
    samples
        Sampled engine: feasible configurations u, shape (k, p).
    packed
        Raster engine: P_φ per angle as :class:`PackedMasks` (always set by
        the raster engine; ``masks`` is also set when the boolean stack is
        small).
    """

    angles: np.ndarray
    regions: tuple[BaseGeometry, ...] | None = None
    masks: Raster | None = None
    count: Raster | None = None
    samples: np.ndarray | None = None
    packed: PackedMasks | None = None

    def mask(self, k: int) -> Raster | None:
        """P at the k-th sampled angle as a boolean Raster (raster engine), else None."""
        if self.masks is not None:
            return Raster(self.masks.grid, self.masks.data[k])
        if self.packed is not None:
            return self.packed.mask(k)
        return None

    def positions(self) -> BaseGeometry | Raster | None:
        """Where the nozzle origin may be at some angle (∪_φ P_φ)."""
        if self.regions is not None:
            import shapely

            return shapely.union_all(list(self.regions))
        if self.masks is not None:
            return Raster(self.masks.grid, self.masks.data.any(axis=0))
        if self.packed is not None:
            return self.packed.any()
        return None


@dataclass(frozen=True, eq=False)
class Components:
    """Connected components of P in configuration space.

    Two pieces of P at consecutive sampled angles are connected when they
    overlap in XY (and the first and last angles wrap on a full turn). The
    count tells how many separate regions a continuous motion must visit;
    with several extruders on one head, separate components can be printed
    at once.

    Attributes
    ----------
    count
        Number of components.
    geometries
        Per component, the union over its angles of the nozzle origin
        positions (XY projection), as shapely geometry; may be None for very
        large raster results.
    angle_ranges
        Per component, (min, max) sampled angle, degrees.
    """

    count: int
    geometries: tuple[BaseGeometry, ...] | None = None
    angle_ranges: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True, eq=False)
class MMCResult:
    """What one nozzle on one machine makes of one layer.

    Attributes
    ----------
    engine
        Engine that produced it (a name from ENGINES).
    nozzle, machine
        The inputs.
    target
        G (shapely MultiPolygon).
    as_built
        S = ∪_u A^u over P, as shapely geometry. For the raster engine it is
        the vectorised *inner* raster estimate (S_inner ⊆ S ⊆ G), or None when
        too large to vectorise; ``as_built_raster`` then holds it.
    as_built_raster
        Raster engine: S_inner on the grid (boolean Raster).
    target_area, as_built_area, lost_area
        λ(G), λ(S) and λ(G \\ S), mm². For the raster engine, the best
        estimate, which lies within ``lost_area_bounds``.
    lost_fraction
        lost_area / target_area.
    lost_area_bounds
        (lo, hi) with lo ≤ exact lost area ≤ hi, mm². For the exact engine
        the interval covers the polygonal approximation of curved nozzles
        (see its docstring); for the raster engine it covers both the grid
        and the angular sampling.
    motion
        The motion restriction P.
    components
        Connected components of P.
    resolution
        Grid spacing h (raster) or the chord tolerance (vector), mm.
    angle_step
        Angular sampling step, degrees (0 when the nozzle does not turn).
    elapsed
        Wall time of the computation, s.
    notes
        Human-readable remarks (approximations made, angles skipped...).
    """

    engine: str
    nozzle: Nozzle
    machine: Machine
    target: BaseGeometry
    as_built: BaseGeometry | None
    target_area: float
    as_built_area: float
    lost_area: float
    lost_area_bounds: tuple[float, float]
    motion: MotionRestriction
    components: Components
    resolution: float
    angle_step: float
    elapsed: float
    as_built_raster: Raster | None = None
    notes: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        # 0 ≤ lo ≤ lost ≤ hi ≤ λ(G) holds for every engine by construction (each
        # clamps its estimate into its bounds); a rounding slack of 10⁻⁹·λ(G)
        lo, hi = self.lost_area_bounds
        values = (self.target_area, self.lost_area, lo, hi)
        slack = 1e-9 * max(abs(self.target_area), 1e-12) + 1e-15
        if not all(np.isfinite(v) for v in values) or not (
            -slack <= lo <= self.lost_area + slack
            and self.lost_area <= hi + slack
            and hi <= self.target_area + slack
        ):
            raise MMCInternalError(
                f"{self.engine} engine: inconsistent lost area {self.lost_area!r} mm² with "
                f"bounds ({lo!r}, {hi!r}) for a part of {self.target_area!r} mm² (need "
                "0 ≤ lower ≤ lost ≤ upper ≤ part area). This is a bug: please report it "
                "with the input."
            )

    @property
    def lost_fraction(self) -> float:
        return self.lost_area / self.target_area if self.target_area > 0 else 0.0

    @property
    def lost(self) -> BaseGeometry | None:
        """G \\ S as geometry (None when S is only known as a raster)."""
        if self.as_built is None:
            return None
        return self.target.difference(self.as_built)
