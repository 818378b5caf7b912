"""What an analysis returns: per layer, per nozzle, for the part, and what refinement did.

:class:`Analysis` is immutable; :meth:`Analysis.to_json` is the JSON contract of
docs/design.md §4, assembled from :meth:`NozzleAnalysis.to_json`,
:meth:`LayerOutcome.to_json` and :meth:`Refinement.to_json`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from printability import __version__
from printability.analysis.ranking import Totals, ties, totals, uses_volume
from printability.mmc import MMCResult
from printability.model.layers import LayerStack
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

__all__ = ["Analysis", "LayerOutcome", "NozzleAnalysis", "Refinement"]


@dataclass(frozen=True)
class LayerOutcome:
    """One nozzle on one layer.

    ``result`` is the full engine result (None when the nozzle fits nowhere in
    the layer, in which case the whole layer is lost, or when results were
    not kept).
    """

    index: int
    z: float
    height: float
    target_area: float
    as_built_area: float
    lost_area: float
    lost_area_bounds: tuple[float, float]
    components: int
    engine: str
    elapsed: float
    result: MMCResult | None = field(default=None, compare=False, repr=False)
    note: str = ""
    resolution: float = 0.0
    angle_step: float = 0.0
    refinements: int = 0

    @property
    def width(self) -> float:
        """hi − lo of the certified lost-area interval, mm²."""
        return self.lost_area_bounds[1] - self.lost_area_bounds[0]

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "z": self.z,
            "height": self.height,
            "target_area": self.target_area,
            "as_built_area": self.as_built_area,
            "lost_area": self.lost_area,
            "lost_area_bounds": list(self.lost_area_bounds),
            "components": self.components,
            "engine": self.engine,
            **({"resolution": self.resolution} if self.resolution else {}),
            **({"angle_step": self.angle_step} if self.angle_step else {}),
            **({"refinements": self.refinements} if self.refinements else {}),
            **({"note": self.note} if self.note else {}),
        }


@dataclass(frozen=True)
class NozzleAnalysis:
    """One nozzle over all layers; areas in mm², volumes in mm³ (Σ area·height).

    ``rank`` is the place in the list (by estimate); ``rank_range`` the ranks the
    certified bounds allow and ``tied_with`` the nozzles whose interval overlaps
    this one's (:mod:`printability.analysis.ranking`). ``allowed_width`` is the width hi − lo
    a ``bound_tolerance`` asked for (in the unit of :meth:`totals`), None without one.
    """

    nozzle: Nozzle
    layers: tuple[LayerOutcome, ...]
    rank: int = 0
    build_time: float = 0.0
    rank_range: tuple[int, int] = (0, 0)
    tied_with: tuple[str, ...] = ()
    allowed_width: float | None = None

    def totals(self, *, volume: bool | None = None) -> Totals:
        """Target, lost and bounds in one unit (:func:`printability.analysis.ranking.totals`)."""
        return totals(self.layers, volume=volume)

    @property
    def tolerance_met(self) -> bool | None:
        """Whether hi − lo is within ``allowed_width`` (None without a tolerance)."""
        if self.allowed_width is None:
            return None
        lo, hi = self.totals().lost_bounds
        return hi - lo <= self.allowed_width * (1 + 1e-12)

    @property
    def target_area(self) -> float:
        return sum(o.target_area for o in self.layers)

    @property
    def as_built_area(self) -> float:
        return sum(o.as_built_area for o in self.layers)

    @property
    def lost_area(self) -> float:
        return sum(o.lost_area for o in self.layers)

    @property
    def lost_area_bounds(self) -> tuple[float, float]:
        return (sum(o.lost_area_bounds[0] for o in self.layers),
                sum(o.lost_area_bounds[1] for o in self.layers))

    @property
    def lost_fraction(self) -> float:
        t = self.target_area
        return self.lost_area / t if t > 0 else 0.0

    @property
    def components(self) -> int:
        """Largest number of configuration-space components in any layer."""
        return max((o.components for o in self.layers), default=0)

    def volume(self, what: str) -> float:
        """Σ over layers of an area attribute times the layer height, mm³."""
        return sum(getattr(o, what) * o.height for o in self.layers)

    def to_json(self, *, multi_layer: bool) -> dict[str, Any]:
        out: dict[str, Any] = {
            "spec": self.nozzle.spec,
            "rank": self.rank,
            "rank_range": list(self.rank_range),
            "rank_certain": self.rank_range[0] == self.rank_range[1],
            "tied_with": list(self.tied_with),
            "target_area": self.target_area,
            "as_built_area": self.as_built_area,
            "lost_area": self.lost_area,
            "lost_fraction": self.lost_fraction,
            "lost_area_bounds": list(self.lost_area_bounds),
            "components": self.components,
            "build_time_estimate_s": self.build_time,
            "layers": [o.to_json() for o in self.layers],
        }
        if multi_layer:
            vol = totals(self.layers, volume=True)
            out.update(
                target_volume=self.volume("target_area"),
                as_built_volume=self.volume("as_built_area"),
                lost_volume=self.volume("lost_area"),
                lost_volume_bounds=list(vol.lost_bounds),
            )
        if self.allowed_width is not None:
            t = self.totals()
            out["bound_tolerance"] = {
                "quantity": t.quantity, "unit": t.unit, "allowed_width": self.allowed_width,
                "width": t.lost_bounds[1] - t.lost_bounds[0], "met": self.tolerance_met}
        return out


@dataclass(frozen=True)
class Analysis:
    """A ranked analysis of one part: ``nozzles`` sorted by rank (best first)."""

    input: str
    machine: Machine
    engine: str
    settings: Settings
    layers: LayerStack
    nozzles: tuple[NozzleAnalysis, ...]
    elapsed: float
    refinement: Refinement | None = None

    @property
    def multi_layer(self) -> bool:
        return len(self.layers) > 1

    @property
    def quantity(self) -> str:
        """``"volume"`` (mm³) or ``"area"`` (mm²): what the ranking compares."""
        return "volume" if uses_volume([lay.height for lay in self.layers]) else "area"

    @property
    def ties(self) -> tuple[tuple[str, str], ...]:
        """Pairs of nozzle SPECs whose certified intervals overlap: not ranked for sure."""
        vol = self.quantity == "volume"
        b = [n.totals(volume=vol).lost_bounds for n in self.nozzles]
        return tuple((self.nozzles[i].nozzle.spec, self.nozzles[j].nozzle.spec)
                     for i, j in ties(b))

    def to_json(self) -> dict[str, Any]:
        """The JSON document of docs/design.md §4 (plain dicts, lists and floats)."""
        return {
            "input": self.input,
            "units": "mm",
            "version": __version__,
            "machine": self.machine.spec,
            "engine": self.engine,
            "resolution": self.settings.resolution,
            "layers": len(self.layers),
            **({"selected_layers": self.layers.meta["selected_layers"]}
               if "selected_layers" in self.layers.meta else {}),
            "elapsed_s": self.elapsed,
            "ranking": {
                "quantity": self.quantity,
                "unit": "mm³" if self.quantity == "volume" else "mm²",
                "certain": not self.ties,
                "ties": [list(t) for t in self.ties],
            },
            **({"refinement": self.refinement.to_json()} if self.refinement is not None else {}),
            "nozzles": [n.to_json(multi_layer=self.multi_layer) for n in self.nozzles],
        }

@dataclass(frozen=True)
class Refinement:
    """What the refinement of :func:`analyze` did and what it cost.

    Attributes
    ----------
    tolerance
        The bound tolerance asked for (text), or None.
    separate_ties
        Whether overlapping intervals were refined.
    rounds, tasks
        Refinement rounds run and layer × nozzle computations they made.
    work
        Their estimated work (units of :func:`raster_work`).
    elapsed
        Wall time of the refinement, s.
    met
        Every nozzle's width within its tolerance (None without a tolerance).
    stopped
        Why refinement ended: ``met``, ``separated``, ``nothing to refine``, ``budget``
        (tie separation's work budget), ``finest`` (no finer setting), ``limit`` (the
        memory or work guard), or ``rounds``.
    notes
        Human-readable remarks.
    """

    tolerance: str | None
    separate_ties: bool
    rounds: int
    tasks: int
    work: float
    elapsed: float
    met: bool | None
    stopped: str
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"tolerance": self.tolerance, "separate_ties": self.separate_ties,
                "rounds": self.rounds, "tasks": self.tasks, "work": self.work,
                "elapsed_s": self.elapsed, "met": self.met, "stopped": self.stopped,
                "notes": list(self.notes)}
