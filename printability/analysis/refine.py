"""Refinement after the first pass: a bound tolerance to meet, ties to separate.

:class:`RefineOptions` says what :func:`printability.analysis.analyze` refines and
within what; :class:`BoundTolerance` is the width a nozzle's certified interval may
have. :func:`precheck_tolerance` refuses, before anything runs, an absolute tolerance
the guards cannot afford; :func:`refine_nozzles` refines, round by round, the layers
whose widths weigh most, at the next finer settings
(:func:`printability.mmc.refine.refined_settings`), intersecting the intervals.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from printability.analysis.ranking import Totals, ties, uses_volume
from printability.errors import InputError, ResourceError
from printability.mmc import choose_engine
from printability.model.layers import Layer, LayerStack
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

from .results import LayerOutcome, NozzleAnalysis, Refinement
from .tasks import TaskRunner
from .work import SECONDS_PER_WORK

__all__ = ["DEFAULT_REFINE_BUDGET", "MAX_REFINE_ROUNDS", "BoundTolerance", "RefineOptions",
           "precheck_tolerance", "refine_nozzles"]

DEFAULT_REFINE_BUDGET = 4.0
"""Work tie separation may add, as a multiple of the first pass's estimated work."""

MAX_REFINE_ROUNDS = 8
"""Most refinement rounds of :func:`printability.analysis.analyze` (each halves the step of
the layers it refines)."""


@dataclass(frozen=True)
class BoundTolerance:
    """How wide a nozzle's certified interval of lost material may be, over the part.

    Attributes
    ----------
    value
        Absolute: the width hi − lo in the ranking's unit (mm² for one layer, mm³
        for several). Relative: a fraction r of the estimated lost amount, with a
        floor of r/100 of the part's size (so ``5%`` allows 5 % of the loss or
        0.05 % of the part, whichever is larger: a part that loses almost nothing
        can still meet it).
    relative
        Whether ``value`` is a fraction.
    text
        As the user wrote it.
    """

    value: float
    relative: bool
    text: str

    @classmethod
    def parse(cls, spec: BoundTolerance | str | float) -> BoundTolerance:
        """From ``0.5`` / ``"0.5"`` (absolute) or ``"5%"`` (relative).

        Raises
        ------
        InputError
            Not a positive finite number (percentages in (0, 100]).
        """
        if isinstance(spec, BoundTolerance):
            return spec
        text = str(spec).strip()
        relative = text.endswith("%")
        try:
            value = float(text[:-1] if relative else text)
        except ValueError:
            value = math.nan
        if relative:
            value /= 100.0
        if not (math.isfinite(value) and value > 0 and (not relative or value <= 1.0)):
            raise InputError(
                f"bound tolerance {text[:40]!r}: expected a positive width in the ranking's "
                "unit (mm² for one layer, mm³ for several), e.g. 0.5, or a percentage of "
                "the lost amount in (0, 100], e.g. 5%")
        return cls(value, relative, text)

    def allowed(self, t: Totals) -> float:
        """The width hi − lo allowed for a nozzle with these totals (its unit)."""
        if self.relative:
            return max(self.value * t.lost, self.value * 0.01 * t.target)
        return self.value


@dataclass(frozen=True, kw_only=True)
class RefineOptions:
    """What :func:`printability.analysis.analyze` refines after its first pass.

    Attributes
    ----------
    bound_tolerance
        Refine until every nozzle's certified interval of what it loses over the
        part (mm² for one layer, mm³ for several: the ranking's unit) is at most
        this wide: a :class:`BoundTolerance` or its text (``"0.5"`` absolute,
        ``"5%"`` relative). None: no such goal.
    separate_ties
        Refine the nozzles whose certified intervals overlap until they separate,
        within ``refine_budget``.
    refine_budget
        Most work tie separation may add, as a multiple of the first pass's
        estimated work (a tolerance is not limited by it, only by the memory and
        work guards).
    max_rounds
        Most refinement rounds (each refines some layers of some nozzles once).
    """

    bound_tolerance: BoundTolerance | str | float | None = None
    separate_ties: bool = False
    refine_budget: float = DEFAULT_REFINE_BUDGET
    max_rounds: int = MAX_REFINE_ROUNDS

    @property
    def active(self) -> bool:
        """Whether there is anything to refine for (a tolerance, or ties to separate)."""
        return self.bound_tolerance is not None or self.separate_ties

    def tolerance(self) -> BoundTolerance | None:
        """The tolerance, parsed, once the options are checked.

        Raises
        ------
        InputError
            The tolerance cannot be read, or ``refine_budget`` is not a finite number ≥ 0.
        """
        tol = (BoundTolerance.parse(self.bound_tolerance)
               if self.bound_tolerance is not None else None)
        if not (self.refine_budget >= 0 and math.isfinite(self.refine_budget)):
            raise InputError(f"analyze: refine_budget must be a finite number ≥ 0; got "
                             f"{self.refine_budget!r}")
        return tol


def _weights(layers: Sequence[LayerOutcome], volume: bool) -> list[float]:
    return [o.height if volume else 1.0 for o in layers]


def _plan_steps(width: float, allowed: float) -> int:
    """Halvings of ``width`` needed to reach ``allowed`` (the raster's width ∝ h)."""
    if width <= allowed or allowed <= 0:
        return 0 if width <= allowed else 60
    return math.ceil(math.log2(width / allowed) - 1e-12)


def _refuse_plan(what: str, layer: Layer, noz: Nozzle, mach: Machine, engine: str,
                 settings: Settings, steps: int, max_work: float) -> None:
    """Refuse (ResourceError) when ``steps`` refinements of this layer would exceed a guard."""
    from printability.mmc.refine import refined_settings, refinement_work

    s = settings
    for _ in range(steps):
        nxt = refined_settings(engine, noz, mach, s)
        if nxt is None:
            break
        s = nxt
    if s is settings:
        return
    work, memory = refinement_work(layer.region, noz, mach, engine, s)
    step = f", angle step {s.angle_step:g}°" if s.angle_step is not None else ""
    if memory > settings.max_memory or work > max_work:
        minutes = work * SECONDS_PER_WORK / 60
        raise ResourceError(
            f"{what}: nozzle {noz.spec} would need about {steps} refinement(s) of layer "
            f"{layer.index} (z={layer.z:g} mm), to --resolution {s.resolution:g} mm{step}: "
            f"about {memory / 2**20:,.0f} MiB (allowed {settings.max_memory / 2**20:,.0f} MiB) "
            f"and {work:.2g} operations, roughly {minutes:,.1f} minutes (allowed {max_work:.2g}); "
            "nothing was refined. Ask for a wider tolerance, or raise --max-memory")


def precheck_tolerance(layers: LayerStack, nozs: Sequence[Nozzle], mach: Machine, engine: str,
                       settings: Settings, tol: BoundTolerance, max_work: float) -> None:
    """Refuse an absolute tolerance that the raster engine cannot meet within the guards.

    Before anything runs, the width is predicted from the boundary length: the plain
    raster engine's interval is about 2·h wide per mm of boundary (see
    :mod:`printability.mmc.raster`); each refinement halves h. Nozzles whose band the
    engine settles below the pixel (one circle or ellipse) are checked after the first
    pass instead, from the width it measured.
    """
    from printability.mmc.raster import band_settles

    volume = uses_volume([lay.height for lay in layers])
    for noz in nozs:
        if band_settles(noz):
            # its upper bound is settled below the pixel: the width is no longer 2·h per mm
            # of boundary, and is only known after the first pass (checked then)
            continue
        widths = []
        for layer in layers:
            eng = choose_engine(noz, mach, layer.region) if engine == "auto" else engine
            if eng != "raster":
                continue
            w = 2.0 * settings.resolution * float(layer.region.length)
            widths.append((w * (layer.height if volume else 1.0), w, layer, eng))
        if not widths:
            continue
        total = sum(w for w, *_ in widths)
        steps = _plan_steps(total, tol.value)
        if steps:
            _, _, layer, eng = max(widths, key=lambda t: t[0])
            _refuse_plan(f"--bound-tolerance {tol.text}", layer, noz, mach, eng, settings,
                         steps, max_work)


def _choose_layers(layers: Sequence[LayerOutcome], weights: Sequence[float], reduce_by: float,
                   ) -> list[int]:
    """Layers to refine so that their widths, halved, reduce the total by ``reduce_by``."""
    order = sorted(range(len(layers)), key=lambda k: -layers[k].width * weights[k])
    chosen, gain = [], 0.0
    for k in order:
        if layers[k].width * weights[k] <= 0:
            break
        chosen.append(k)
        gain += 0.5 * layers[k].width * weights[k]
        if gain >= reduce_by:
            break
    return chosen


def _merge(old: LayerOutcome, new: LayerOutcome) -> LayerOutcome:
    """A layer's refined outcome: the intersection of both certified intervals."""
    from printability.mmc.refine import merge_bounds

    lo, hi = merge_bounds(old.lost_area_bounds, new.lost_area_bounds,
                          target_area=old.target_area)
    lost = min(max(new.lost_area, lo), hi)
    return replace(new, lost_area=lost, as_built_area=old.target_area - lost,
                   lost_area_bounds=(lo, hi), elapsed=old.elapsed + new.elapsed,
                   refinements=old.refinements + 1)



@dataclass
class _State:
    """The refinement so far: the nozzles' outcomes, each (nozzle, layer)'s settings, the
    layers that cannot be refined further, notes, and what the rounds cost."""

    per: list[NozzleAnalysis]
    cur: dict[tuple[int, int], Settings]
    first_work: float
    blocked: set[tuple[int, int]] = field(default_factory=set)
    notes: list[str] = field(default_factory=list)
    spent: float = 0.0
    rounds: int = 0
    tasks: int = 0


@dataclass
class _Round:
    """The computations one round will run: tasks, their (nozzle, layer, settings) keys,
    their estimated work, and why some layers were left out."""

    tasks: list[tuple] = field(default_factory=list)
    keys: list[tuple[int, int, Settings]] = field(default_factory=list)
    work: float = 0.0
    reasons: set[str] = field(default_factory=set)

    def stop_reason(self) -> str:
        """Why refinement ends when this round has nothing to run."""
        return ("limit" if "limit" in self.reasons else "budget" if "budget" in self.reasons
                else "finest" if "finest" in self.reasons else "nothing to refine")


@dataclass(frozen=True)
class _Refiner:
    """One analysis's refinement: the part, its goals and guards, and where tasks run."""

    layers: LayerStack
    machine: Machine
    tol: BoundTolerance | None
    options: RefineOptions
    max_work: float
    runner: TaskRunner
    volume: bool

    @property
    def settings(self) -> Settings:
        return self.runner.settings

    def start(self, per_nozzle: list[NozzleAnalysis]) -> _State:
        """The state before the first round; the first pass's estimated work."""
        from printability.mmc.refine import refinement_work

        per = list(per_nozzle)
        n_layers = len(self.layers)
        cur = {(i, k): self.settings for i in range(len(per)) for k in range(n_layers)}
        first_work = sum(refinement_work(self.layers[k].region, per[i].nozzle, self.machine,
                                         per[i].layers[k].engine, self.settings)[0]
                         for i in range(len(per)) for k in range(n_layers))
        return _State(per, cur, first_work)

    def run(self, state: _State) -> str:
        """Refine round after round; returns why it stopped (:attr:`Refinement.stopped`)."""
        while True:
            tots = [n.totals(volume=self.volume) for n in state.per]
            want, tol_needed = self._wanted(tots)
            if not want:
                return ("met" if self.tol is not None
                        else "separated" if self.options.separate_ties else "nothing to refine")
            if state.rounds >= self.options.max_rounds:
                return "rounds"
            rnd = self._plan_round(state, tots, want, tol_needed)
            if not rnd.tasks:
                return rnd.stop_reason()
            self._run_round(state, rnd)

    def _wanted(self, tots: list[Totals]) -> tuple[dict[int, float], bool]:
        """Per nozzle, the reduction of its total width wanted; and whether the tolerance
        (not only the ties) wants some."""
        want: dict[int, float] = {}  # nozzle -> total width reduction wanted
        for i, t in enumerate(tots):
            if self.tol is not None:
                width = t.lost_bounds[1] - t.lost_bounds[0]
                allowed = self.tol.allowed(t)
                if width > allowed * (1 + 1e-12):
                    want[i] = max(want.get(i, 0.0), width - allowed)
        tol_needed = bool(want)
        if self.options.separate_ties:
            _want_separation(tots, want)
        return want, tol_needed

    def _plan_round(self, state: _State, tots: list[Totals], want: dict[int, float],
                    tol_needed: bool) -> _Round:
        """The layers to refine this round, per nozzle that wants it, within the guards."""
        rnd = _Round()
        for i, reduce_by in want.items():
            n = state.per[i]
            for k in _choose_layers(n.layers, _weights(n.layers, self.volume), reduce_by):
                if (i, k) not in state.blocked:
                    self._plan_layer(state, rnd, i, k, tots[i], tol_needed)
        return rnd

    def _plan_layer(self, state: _State, rnd: _Round, i: int, k: int, t: Totals,
                    tol_needed: bool) -> None:
        """Add layer k of nozzle i to the round at its next finer settings, or say why not."""
        from printability.mmc.refine import refined_settings, refinement_work

        n = state.per[i]
        o = n.layers[k]
        nxt = refined_settings(o.engine, n.nozzle, self.machine, state.cur[(i, k)])
        if nxt is None:
            state.blocked.add((i, k))
            rnd.reasons.add("finest")
            return
        if tol_needed and self.tol is not None:
            steps = _plan_steps(t.lost_bounds[1] - t.lost_bounds[0], self.tol.allowed(t))
            _refuse_plan(f"--bound-tolerance {self.tol.text}", self.layers[k], n.nozzle,
                         self.machine, o.engine, state.cur[(i, k)], steps, self.max_work)
        work, memory = refinement_work(self.layers[k].region, n.nozzle, self.machine, o.engine,
                                       nxt)
        if memory > self.settings.max_memory or work > self.max_work:
            state.blocked.add((i, k))
            rnd.reasons.add("limit")
            state.notes.append(f"{n.nozzle.spec}, layer {o.index}: not refined past "
                               f"resolution {state.cur[(i, k)].resolution:g} mm (the next step "
                               f"needs about {memory / 2**20:,.0f} MiB, {work:.2g} work)")
            return
        only_ties = not (self.tol is not None and tol_needed)
        if only_ties and state.spent + rnd.work + work > (self.options.refine_budget
                                                          * state.first_work):
            rnd.reasons.add("budget")
            return
        rnd.tasks.append(self.runner.task(self.layers[k], n.nozzle, self.machine, o.engine, nxt))
        rnd.keys.append((i, k, nxt))
        rnd.work += work

    def _run_round(self, state: _State, rnd: _Round) -> None:
        """Run the round's tasks and intersect each refined layer's interval with its own."""
        outs = self.runner.run(rnd.tasks)
        for (i, k, nxt), new in zip(rnd.keys, outs, strict=True):
            lay = list(state.per[i].layers)
            lay[k] = _merge(lay[k], new)
            state.per[i] = replace(state.per[i], layers=tuple(lay))
            state.cur[(i, k)] = nxt
        state.spent += rnd.work
        state.rounds += 1
        state.tasks += len(rnd.tasks)

    def finish(self, state: _State, stopped: str, t0: float,
               ) -> tuple[list[NozzleAnalysis], Refinement]:
        """The refined nozzles (with the width their tolerance allows) and the record."""
        per, met = state.per, None
        if self.tol is not None:
            per = [replace(n, allowed_width=self.tol.allowed(n.totals(volume=self.volume)))
                   for n in per]
            met = all(bool(n.tolerance_met) for n in per)
        return per, Refinement(
            tolerance=self.tol.text if self.tol is not None else None,
            separate_ties=self.options.separate_ties, rounds=state.rounds, tasks=state.tasks,
            work=state.spent, elapsed=time.perf_counter() - t0, met=met, stopped=stopped,
            notes=tuple(dict.fromkeys(state.notes)))


def _want_separation(tots: list[Totals], want: dict[int, float]) -> None:
    """Add to ``want`` the width reductions that would separate overlapping intervals (the
    wider of a pair, or both when alike); equal to rounding is a true tie, left alone."""
    bounds = [t.lost_bounds for t in tots]
    for i, j in ties(bounds):
        wi = bounds[i][1] - bounds[i][0]
        wj = bounds[j][1] - bounds[j][0]
        floor = 1e-9 * max(tots[i].target, tots[j].target)
        if wi <= floor and wj <= floor:
            continue  # equal to rounding: a true tie, broken by build time
        overlap = min(bounds[i][1], bounds[j][1]) - max(bounds[i][0], bounds[j][0])
        for k, w in ((i, wi), (j, wj)):
            if w >= 0.25 * (wi + wj):
                want[k] = max(want.get(k, 0.0), min(w, overlap + 1e-12))


def refine_nozzles(per_nozzle: list[NozzleAnalysis], layers: LayerStack, machine: Machine, *,
                   tol: BoundTolerance | None, options: RefineOptions, max_work: float,
                   runner: TaskRunner) -> tuple[list[NozzleAnalysis], Refinement]:
    """Refine layers of some nozzles until the tolerance is met and/or ties separate.

    Each round picks, per nozzle that needs it, the layers whose widths weigh most
    (:func:`_choose_layers`), computes them again at the next finer settings
    (:func:`printability.mmc.refine.refined_settings`) and intersects the intervals.
    A tolerance whose predicted cost exceeds the memory or work guard is refused
    before its round runs (:func:`_refuse_plan`). Tie separation stops at
    ``options.refine_budget`` times the first pass's estimated work, any refinement at
    ``options.max_rounds`` rounds; a layer is left as it is when its next step would
    exceed ``runner.settings.max_memory`` or ``max_work``.
    """
    t0 = time.perf_counter()
    refiner = _Refiner(layers, machine, tol, options, max_work, runner,
                       volume=uses_volume([lay.height for lay in layers]))
    state = refiner.start(per_nozzle)
    stopped = refiner.run(state)
    return refiner.finish(state, stopped, t0)
