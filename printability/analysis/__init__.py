"""Analyse a sliced part for several nozzles on one machine: per layer, per nozzle.

:func:`analyze` runs :func:`printability.mmc.compute_mmc` on every layer of a
:class:`~printability.model.layers.LayerStack` for every candidate nozzle, sums
areas and volumes, ranks the nozzles (:mod:`printability.analysis.ranking`) and returns
an immutable :class:`Analysis` whose :meth:`Analysis.to_json` is the JSON
contract of docs/design.md §4.

Layers are independent, so they run in parallel: ``settings.workers``
processes on this machine, or a Dask cluster when ``scheduler`` names one
(the ``dask`` extra).

The modules, one responsibility each: :mod:`.pipeline` (:func:`analyze`, stage by
stage), :mod:`.results` (what it returns, and the JSON), :mod:`.tasks` (one layer ×
nozzle, and where tasks run), :mod:`.work` (the raster engine's work and its guard),
:mod:`.refine` (bound tolerances and tie separation) and :mod:`.selection`
(``--layers``).
"""

from __future__ import annotations

from .pipeline import analyze
from .refine import DEFAULT_REFINE_BUDGET, MAX_REFINE_ROUNDS, BoundTolerance, RefineOptions
from .results import Analysis, LayerOutcome, NozzleAnalysis, Refinement
from .selection import select_layers
from .work import RASTER_WORK_BUDGET, raster_work

__all__ = ["DEFAULT_REFINE_BUDGET", "MAX_REFINE_ROUNDS", "RASTER_WORK_BUDGET", "Analysis",
           "BoundTolerance", "LayerOutcome", "NozzleAnalysis", "RefineOptions", "Refinement",
           "analyze", "raster_work", "select_layers"]
