"""What a post-processing run is for: :class:`PostprocessOptions` (checked as they are made),
the slicer settings a PrusaSlicer-family slicer exports to its scripts, and the number of
worker threads."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field

from printability.errors import InputError, excerpt
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.planning.orientation import OrientationOptions


def _check_range(name: str, value: float, lo: float, hi: float, unit: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (lo <= value <= hi):
        unit = " " + unit if unit else ""
        raise InputError(f"{name} expects a number from {lo:g} to {hi:g}{unit}; "
                         f"found {excerpt(str(value))}")


def _check_output_name(name: str) -> None:
    """A file name for the slicer to give its output: one name, no folder, no control
    character (the slicer renames its file to it; ``../../x`` would move it elsewhere)."""
    bad = (not name or name in (".", "..") or "/" in name or "\\" in name
           or any(ord(c) < 32 or ord(c) == 127 for c in name)
           or len(name.encode("utf-8")) > 255)
    if bad:
        shown = name[:60].encode("unicode_escape").decode("ascii")
        raise InputError(f"output name expects a file name (no folder, no control characters, "
                         f"at most 255 bytes); found {shown!r}")


@dataclass(frozen=True)
class PostprocessOptions:
    """What to post-process for.

    Attributes
    ----------
    nozzle
        Nozzle SPEC or object; None: a round nozzle of the slicer's
        ``nozzle_diameter`` (SLIC3R_NOZZLE_DIAMETER).
    machine
        Machine SPEC or object (default ``ttr``: a full-turn rotary C axis).
    tolerance
        How far a swept footprint may stand outside the target, mm.
    feed_policy
        Overrides the machine's; one of ``xy`` or ``euclidean``
        (``inverse-time`` needs an F on every move, which would rewrite
        every line: use ``printability generate``).
    letter
        Overrides the machine's rotary letter.
    unwind
        Cabled head: bring the axis back towards 0 on travel moves.
    e_policy
        One of :data:`printability.options.E_POLICIES`.
    filament_diameter, layer_height
        Override what the file or the slicer's environment says, mm.
    angle_decimals
        Precision of rotary words.
    chord_tolerance
        Linearisation of arcs, mm.
    workers
        Threads that rebuild the layer targets (compiled kernels and GEOS
        release the GIL) while the planner runs, and that the planner's footprint
        tests are shared out over; None: one per CPU core, at most 4. The output
        is the same bytes on any number.
    interior
        Plan against the object: the slicer's beads with the gaps it leaves inside the object
        (sparse infill) filled back (:func:`printability.sources.gcode.fill_interior`), so a
        footprint may reach into a gap it would not leave the part through. False: against
        the beads alone (the nozzle never covers a spot the slicer leaves empty; more turns
        standing still, and a slower print).
    allow_empty
        Write the file even when the nozzle prints none of the part (by default
        that is a :class:`NozzleTooLargeError` and the file is left alone).
    output_name
        New final file name to hand back to the slicer through the
        ``<gcode>.output_name`` file (PrusaSlicer ≥ 2.4 convention); None
        leaves the name alone.
    """

    nozzle: str | Nozzle | None = None
    machine: str | Machine = "ttr"
    tolerance: float = 1e-3
    feed_policy: str | None = None
    letter: str | None = None
    unwind: bool = False
    e_policy: str = "width"
    filament_diameter: float | None = None
    layer_height: float | None = None
    angle_decimals: int = 3
    chord_tolerance: float = 0.002
    output_name: str | None = None
    workers: int | None = None
    orientation: OrientationOptions = field(default_factory=OrientationOptions)
    allow_empty: bool = False
    interior: bool = True

    def __post_init__(self) -> None:
        if self.output_name is not None:
            _check_output_name(self.output_name)
        _check_range("tolerance", self.tolerance, 0.0, 1.0, "mm")
        _check_range("chord tolerance", self.chord_tolerance, 1e-6, 1.0, "mm")
        _check_range("angle decimals", self.angle_decimals, 0, 9, "")
        for key, value in (("filament diameter", self.filament_diameter),
                           ("layer height", self.layer_height)):
            if value is not None:
                _check_range(key, value, 1e-3, 100.0, "mm")


#: The options of a run that is given none (the defaults of every field)
DEFAULT_OPTIONS = PostprocessOptions()


def worker_count(options: PostprocessOptions) -> int:
    """The threads a run uses: ``options.workers``, else one per CPU core, at most 4."""
    if options.workers is not None:
        if options.workers < 1:
            raise InputError(f"workers must be at least 1; got {options.workers!r}")
        return int(options.workers)
    return max(1, min(4, os.cpu_count() or 1))


# ----------------------------------------------------------------- environment


def _env_float(env: Mapping[str, str], key: str) -> float | None:
    """First number of a SLIC3R_* value (per-extruder values are comma separated)."""
    raw = env.get(key)
    if raw is None or not raw.strip():
        return None
    first = raw.split(",")[0].strip().rstrip("%")
    try:
        value = float(first)
    except ValueError:
        raise InputError(f"environment variable {key}={excerpt(raw)}: expected a number") from None
    return value


def settings_from_environment(env: Mapping[str, str] | None = None) -> dict[str, object]:
    """The slicer settings a PrusaSlicer-family slicer exports to its scripts.

    PrusaSlicer, SuperSlicer and OrcaSlicer export every print setting as an
    environment variable ``SLIC3R_<KEY>`` (upper case; vectors comma
    separated, one value per extruder) and ``SLIC3R_PP_OUTPUT_NAME`` (the
    final name of the file). Recognised here: ``NOZZLE_DIAMETER``,
    ``LAYER_HEIGHT``, ``FILAMENT_DIAMETER``, ``EXTRUSION_WIDTH``,
    ``PERIMETER_EXTRUSION_WIDTH``, ``EXTERNAL_PERIMETER_EXTRUSION_WIDTH``,
    ``USE_RELATIVE_E_DISTANCES``, ``ARC_FITTING`` (PrusaSlicer ≥ 2.6) /
    ``ENABLE_ARC_FITTING`` (OrcaSlicer), ``GCODE_FLAVOR``, ``PP_OUTPUT_NAME``.

    Returns
    -------
    dict
        Only the keys found, with lower-case names (``nozzle_diameter``...).
    """
    env = os.environ if env is None else env
    out: dict[str, object] = {}
    for key in ("NOZZLE_DIAMETER", "LAYER_HEIGHT", "FILAMENT_DIAMETER", "EXTRUSION_WIDTH",
                "PERIMETER_EXTRUSION_WIDTH", "EXTERNAL_PERIMETER_EXTRUSION_WIDTH"):
        v = _env_float(env, "SLIC3R_" + key)
        if v is not None:
            out[key.lower()] = v
    rel = env.get("SLIC3R_USE_RELATIVE_E_DISTANCES")
    if rel is not None and rel.strip():
        out["use_relative_e_distances"] = rel.strip().lower() in ("1", "true", "yes")
    arc = env.get("SLIC3R_ARC_FITTING") or env.get("SLIC3R_ENABLE_ARC_FITTING")
    if arc is not None and arc.strip():
        out["arc_fitting"] = arc.strip().lower() not in ("0", "false", "disabled", "no")
    for key in ("GCODE_FLAVOR", "PP_OUTPUT_NAME"):
        if env.get("SLIC3R_" + key):
            out[key.lower()] = env["SLIC3R_" + key]
    return out
