"""Machines: the motion M: Ω → SE(2) that places the nozzle over a layer.

Three kinds (:data:`printability.options.MACHINE_KINDS`):

``xy``
    Two free translations; u = t, m(u)x = x + t. Separable.
``ttr``
    Two free translations plus a rotary axis turning the nozzle about its own
    origin: u = (t, φ), m(u)x = R(φ)x + t, φ in [min, max] sampled every
    ``step`` degrees. Separable.
``chain``
    A planar serial chain of prismatic / revolute joints read from TOML (a
    polar printer whose bed turns under a radial arm, a SCARA arm...). Its
    translations depend on its rotations, so it is *not* separable: the
    sampled engine explores Ω directly.

Machine SPEC: ``xy``, ``ttr``, ``ttr:min=-90,max=90,step=1,letter=C``, or the
path of a TOML profile. A profile also carries what G-code output and the
simulator need (rotary letter, bed, firmware flavor, feed policy, filament
diameter, temperatures); see ``printability/data/machines/*.toml``.

Chain kinematics (planar, angles in degrees): starting from the identity,
each joint applies its fixed ``offset`` (mm) and ``twist`` (deg) and then its
motion — a translation q·axis (prismatic) or a rotation by q about its local
origin (revolute); the ``[tool]`` offset and angle come last. The resulting
pose (R(φ), t) places the nozzle: A^u = R(φ)·A⁰ + t.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from gcode.flavors import Flavor, PlannerLimits, RotaryAxis, flavor_named
from printability.errors import FileFormatError, InputError, PrintabilityOSError, excerpt
from printability.options import FEED_POLICIES, FLAVORS, JOINT_KINDS, MACHINE_KINDS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["DEFAULT_BED", "DEFAULT_TTR_STEP", "Joint", "Machine", "builtin_profiles",
           "parse_machine"]

DEFAULT_TTR_STEP = 2.0
#: The bed of the built-in ``xy`` and ``ttr`` specs, (xmin, xmax, ymin, ymax) in mm: a
#: common 220 mm × 220 mm bed with its origin at the front left corner.
DEFAULT_BED = (0.0, 220.0, 0.0, 220.0)
_DATA = Path(__file__).parents[1] / "data" / "machines"


@dataclass(frozen=True)
class Joint:
    """One joint of a planar chain; lengths in mm, angles in degrees."""

    name: str
    kind: str
    lo: float
    hi: float
    step: float
    axis: tuple[float, float] = (1.0, 0.0)
    offset: tuple[float, float] = (0.0, 0.0)
    twist: float = 0.0

    def values(self) -> np.ndarray:
        """The sampled joint values from lo to hi inclusive (a full turn omits hi)."""
        span = self.hi - self.lo
        n = max(1, round(span / self.step))
        full_turn = self.kind == "revolute" and span >= 360.0 - 1e-9
        vals = self.lo + np.arange(n + (0 if full_turn else 1)) * (span / n)
        return vals


@dataclass(frozen=True)
class Machine:
    """A machine: kinematics plus the profile the G-code side needs.

    Attributes
    ----------
    kind
        ``xy``, ``ttr`` or ``chain``.
    angle_min, angle_max, angle_step
        Rotary range and sampling step for ``ttr``, degrees.
    rotary_letter
        The G-code word of the rotary axis (ISO 841: C turns about Z).
    joints, tool_offset, tool_angle
        The chain of a ``chain`` machine.
    bed
        (xmin, xmax, ymin, ymax) of the reachable bed, mm. The built-in specs
        (``xy``, ``ttr``) have :data:`DEFAULT_BED`; a profile without ``[bed]``
        has none (its part keeps its own coordinates).
    flavor
        Name from :data:`printability.options.FLAVORS`, or None when the spec
        does not say (post-processing then follows the file's own flavor
        comment; see :meth:`firmware`).
    feed_policy
        From ``FEED_POLICIES``, or None: the flavor's (:meth:`feed_policy_for`).
    rotary
        The rotary axis's letter, limits, speed, acceleration and corner
        velocity (:class:`gcode.flavors.RotaryAxis`), for ``ttr`` machines.
    planner
        The firmware's motion limits (``[planner]``; Klipper's defaults when
        absent) for the print-time estimate (:mod:`gcode.printtime`).
    filament_diameter
        mm.
    profile
        The whole TOML document (read-only) for sections other modules own
        (``[temperatures]``, ``[retraction]``, ``[gcode]``...).
    """

    name: str
    kind: str
    spec: str
    angle_min: float = 0.0
    angle_max: float = 0.0
    angle_step: float = DEFAULT_TTR_STEP
    rotary_letter: str = "C"
    joints: tuple[Joint, ...] = ()
    tool_offset: tuple[float, float] = (0.0, 0.0)
    tool_angle: float = 0.0
    bed: tuple[float, float, float, float] | None = None
    flavor: str | None = None
    feed_policy: str | None = None
    rotary: RotaryAxis | None = None
    planner: PlannerLimits = field(default_factory=PlannerLimits)
    filament_diameter: float = 1.75
    profile: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def firmware(self, detected: str | None = None) -> Flavor:
        """The firmware flavor: the machine's, else ``detected`` (a file's own ``;FLAVOR``
        comment), else Marlin."""
        return flavor_named(self.flavor or detected or "marlin")

    def feed_policy_for(self, flavor: Flavor) -> str:
        """The feed policy: the machine's when stated, else the flavor's."""
        return self.feed_policy or flavor.feed_policy

    @property
    def rotary_axis(self) -> RotaryAxis:
        """:attr:`rotary`, or the default axis with this machine's letter and limits."""
        if self.rotary is not None:
            return self.rotary
        lo, hi = (self.angle_min, self.angle_max) if self.kind == "ttr" else (0.0, 0.0)
        return RotaryAxis(letter=self.rotary_letter, min_angle=lo, max_angle=hi)

    @property
    def separable(self) -> bool:
        """True when all translations are free (XY, T-T-R): the fast engines apply."""
        return self.kind in ("xy", "ttr")

    @property
    def has_rotary(self) -> bool:
        return self.kind == "ttr"

    @property
    def full_turn(self) -> bool:
        return self.kind == "ttr" and self.angle_max - self.angle_min >= 360.0 - 1e-9

    def turns(self, nozzle) -> bool:
        """Whether this machine turns ``nozzle``: a rotary axis, and a nozzle that is not
        round (a round one looks the same at every angle: period 0). The one place that
        says it; every stage asks here."""
        return self.has_rotary and nozzle.symmetry_period != 0.0

    def covers_period(self, period: float) -> bool:
        """Whether the rotary range reaches every orientation of a nozzle whose shape
        repeats every ``period`` degrees (360: none): True on an endless axis, or a range at
        least one period wide. False on a machine without a rotary axis."""
        return self.has_rotary and self.angle_max - self.angle_min >= period - 1e-9

    def angles(self, *, step: float | None = None, period: float = 360.0) -> np.ndarray:
        """Rotary angles to sample, degrees.

        Parameters
        ----------
        step
            Overrides the machine's step.
        period
            Symmetry period of the nozzle (see :attr:`Nozzle.symmetry_period`);
            on a full-turn machine only [min, min + period) is needed. A period
            of 0 (round nozzle) needs a single angle.

        An XY machine has the single angle 0. A limited range is sampled at
        both ends, with the step shrunk to divide it evenly.
        """
        if self.kind != "ttr" or period == 0.0:
            return np.array([self.angle_min if self.kind == "ttr" else 0.0])
        step = self.angle_step if step is None else step
        lo, hi = self.angle_min, self.angle_max
        span = hi - lo
        if self.full_turn or (0 < period < 360.0 and span >= period - 1e-9):
            span = min(period, 360.0)
            n = max(1, math.ceil(span / step - 1e-9))
            return lo + np.arange(n) * (span / n)
        n = max(1, math.ceil(span / step - 1e-9))
        return lo + np.arange(n + 1) * (span / n)

    def pose(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses of a chain for joint vectors ``u`` of shape (k, p).

        Returns
        -------
        phi : ndarray (k,)
            Nozzle orientation, degrees (mounting angle not included).
        t : ndarray (k, 2)
            Position of the nozzle origin, mm.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        k = u.shape[0]
        if self.kind != "chain":
            if self.kind == "ttr":
                return u[:, 2].copy(), u[:, :2].copy()
            return np.zeros(k), u[:, :2].copy()
        if u.shape[1] != len(self.joints):
            raise InputError(f"machine {self.name}: expected {len(self.joints)} joint values per "
                             f"configuration; got {u.shape[1]}")
        phi = np.zeros(k)
        t = np.zeros((k, 2))

        def advance(dx: float | np.ndarray, dy: float | np.ndarray) -> None:
            c, s = np.cos(np.deg2rad(phi)), np.sin(np.deg2rad(phi))
            t[:, 0] += c * dx - s * dy
            t[:, 1] += s * dx + c * dy

        for j, joint in enumerate(self.joints):
            advance(*joint.offset)
            phi += joint.twist
            if joint.kind == "revolute":
                phi += u[:, j]
            else:
                advance(u[:, j] * joint.axis[0], u[:, j] * joint.axis[1])
        advance(*self.tool_offset)
        phi += self.tool_angle
        return phi, t

    def joint_grid(self) -> list[np.ndarray]:
        """Sampled values of every joint of a chain (the product is the sampled Ω)."""
        return [j.values() for j in self.joints]


# --------------------------------------------------------------------------- parsing


def _shown(value: Any) -> str:
    """``value`` (from a file or the command line) for a message: a number as it is, anything
    else as a short excerpt (:func:`printability.errors.excerpt`)."""
    if isinstance(value, (int, float)):
        return repr(value)
    return excerpt(value if isinstance(value, str) else repr(value))


def _num(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{where}: {key} expects a finite number; found {_shown(value)}")
    return float(value)


def _pair(where: str, key: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise InputError(f"{where}: {key} expects a pair [a, b]; found {_shown(value)}")
    return (_num(where, key, value[0]), _num(where, key, value[1]))


#: The finest rotary step the analysis samples, degrees (360 000 orientations a turn).
MIN_ANGLE_STEP = 1e-3


def _rotary_range(where: str, lo: float, hi: float, step: float) -> None:
    for name, v in (("min", lo), ("max", hi), ("step", step)):
        if not math.isfinite(v):
            raise InputError(f"{where}: rotary {name} must be a finite number of degrees; "
                             f"found {v!r}")
    if step < MIN_ANGLE_STEP:
        raise InputError(f"{where}: rotary step must be at least {MIN_ANGLE_STEP:g} degrees "
                         f"(finer would sample more orientations than fit in memory); found "
                         f"{step:g}")
    if hi < lo:
        raise InputError(f"{where}: rotary max ({hi:g}°) is below min ({lo:g}°)")
    if hi - lo > 360.0 + 1e-9:
        raise InputError(f"{where}: rotary range {hi - lo:g}° exceeds a full turn (360°)")
    if not (0 < step <= 360):
        raise InputError(f"{where}: rotary step must be in (0, 360] degrees; found {step:g}")


def _from_profile(doc: Mapping[str, Any], where: str, spec: str) -> Machine:
    known = {"machine", "rotary", "joints", "tool", "bed", "firmware", "extruder",
             "temperatures", "retraction", "gcode", "speeds", "planner"}
    for key in doc:
        if key not in known:
            raise FileFormatError(where, f"unknown table [{key}]; expected one of: "
                                  f"{', '.join(sorted(known))}", element=f"[{key}]")
    m = doc.get("machine", {})
    name = str(m.get("name", Path(where).stem))
    try:
        kind = MACHINE_KINDS.check(m.get("kind", "xy"))
    except InputError as exc:
        raise FileFormatError(where, str(exc), element="[machine] kind") from None
    kw: dict[str, Any] = {}
    rot = doc.get("rotary", {})
    if kind == "ttr":
        lo = _num(where, "[rotary] min", rot.get("min", -180.0))
        hi = _num(where, "[rotary] max", rot.get("max", 180.0))
        step = _num(where, "[rotary] step", rot.get("step", DEFAULT_TTR_STEP))
        _rotary_range(where, lo, hi, step)
        kw.update(angle_min=lo, angle_max=hi, angle_step=step)
    if "letter" in rot:
        kw["rotary_letter"] = _letter(where, rot["letter"])
    if kind == "ttr":
        kw["rotary"] = _rotary_axis(where, rot, kw.get("rotary_letter", "C"),
                                    kw["angle_min"], kw["angle_max"])
    if kind == "chain":
        joints = doc.get("joints")
        if not isinstance(joints, list) or not joints:
            raise FileFormatError(where, "a chain machine needs at least one [[joints]] table",
                                  element="[[joints]]")
        out = []
        for i, jd in enumerate(joints):
            jw = f"{where} [[joints]] #{i + 1}"
            try:
                jkind = JOINT_KINDS.check(jd.get("kind"))
            except InputError as exc:
                raise InputError(f"{jw}: {exc}") from None
            lo = _num(jw, "min", jd.get("min"))
            hi = _num(jw, "max", jd.get("max"))
            step = _num(jw, "step", jd.get("step", 1.0))
            if hi < lo or step <= 0:
                raise InputError(f"{jw}: expected min <= max and step > 0; found min={lo:g}, "
                                 f"max={hi:g}, step={step:g}")
            axis = _pair(jw, "axis", jd.get("axis", [1.0, 0.0]))
            if jkind == "prismatic":
                norm = math.hypot(*axis)
                if norm == 0:
                    raise InputError(f"{jw}: axis must not be the zero vector")
                axis = (axis[0] / norm, axis[1] / norm)
            out.append(Joint(str(jd.get("name", f"J{i + 1}")), jkind, lo, hi, step, axis,
                             _pair(jw, "offset", jd.get("offset", [0.0, 0.0])),
                             _num(jw, "twist", jd.get("twist", 0.0))))
        kw["joints"] = tuple(out)
        tool = doc.get("tool", {})
        kw["tool_offset"] = _pair(where, "[tool] offset", tool.get("offset", [0.0, 0.0]))
        kw["tool_angle"] = _num(where, "[tool] angle", tool.get("angle", 0.0))
    bed = doc.get("bed")
    if bed is not None:
        bx = _pair(where, "[bed] x", bed.get("x"))
        by = _pair(where, "[bed] y", bed.get("y"))
        if not (bx[0] < bx[1] and by[0] < by[1]):
            raise FileFormatError(where, f"the bed expects x = [min, max] and y = [min, max] "
                                  f"with min < max; found x = {list(bx)}, y = {list(by)}",
                                  element="[bed]")
        kw["bed"] = (bx[0], bx[1], by[0], by[1])
    fw = doc.get("firmware", {})
    try:
        kw["flavor"] = FLAVORS.check(fw.get("flavor", "marlin"))
        if "feed_policy" in fw:
            kw["feed_policy"] = FEED_POLICIES.check(fw["feed_policy"])
    except InputError as exc:
        raise FileFormatError(where, str(exc), element="[firmware]") from None
    ex = doc.get("extruder", {})
    fd = _num(where, "[extruder] filament_diameter", ex.get("filament_diameter", 1.75))
    if fd <= 0:
        raise InputError(f"{where}: [extruder] filament_diameter must be positive")
    kw["filament_diameter"] = fd
    kw["planner"] = _planner(where, doc.get("planner", {}), fd)
    return Machine(name=name, kind=kind, spec=spec, profile=MappingProxyType(dict(doc)), **kw)


_ROTARY_KEYS = {"letter", "min", "max", "step", "max_speed", "acceleration", "corner_velocity",
                "stepper"}


def _rotary_axis(where: str, rot: Mapping[str, Any], letter: str, lo: float,
                 hi: float) -> RotaryAxis:
    """The ``[rotary]`` table's axis: limits and what the firmware's planner needs."""
    for key in rot:
        if key not in _ROTARY_KEYS:
            raise FileFormatError(where, f"unknown key {_shown(key)}; expected one of: "
                                  f"{', '.join(sorted(_ROTARY_KEYS))}", element="[rotary]")
    d = RotaryAxis()
    kw: dict[str, Any] = {}
    for key, low, high, unit in (("max_speed", 1.0, 1e5, "°/s"),
                                 ("acceleration", 1.0, 1e7, "°/s²"),
                                 ("corner_velocity", 0.0, 1e5, "°/s")):
        v = _num(where, f"[rotary] {key}", rot.get(key, getattr(d, key)))
        if not (low <= v <= high):
            raise FileFormatError(where, f"{key} expects a number of {unit} in [{low:g}, "
                                  f"{high:g}]; found {v:g}", element="[rotary]")
        kw[key] = v
    stepper = rot.get("stepper", d.stepper)
    if not isinstance(stepper, str) or not stepper or not stepper.replace("_", "").isalnum():
        raise FileFormatError(where, "stepper expects the name of a Klipper [manual_stepper] "
                              f"section (letters, digits, _); found {_shown(stepper)}",
                              element="[rotary]")
    full = hi - lo >= 360.0 - 1e-9
    return RotaryAxis(letter=letter, min_angle=-math.inf if full else lo,
                      max_angle=math.inf if full else hi, stepper=stepper, **kw)


def _planner(where: str, table: Any, filament_diameter: float) -> PlannerLimits:
    """The ``[planner]`` table: the firmware's motion limits (mm, s)."""
    if not isinstance(table, Mapping):
        raise FileFormatError(where, "expected a table of motion limits", element="[planner]")
    names = [k for k in PlannerLimits.__dataclass_fields__ if k != "filament_diameter"]
    kw: dict[str, Any] = {"filament_diameter": filament_diameter}
    for key, value in table.items():
        if key not in names:
            raise FileFormatError(where, f"unknown key {_shown(key)}; expected one of: "
                                  f"{', '.join(names)}", element="[planner]")
        kw[key] = _num(where, f"[planner] {key}", value)
    try:
        return PlannerLimits(**kw)
    except ValueError as exc:
        raise FileFormatError(where, str(exc), element="[planner]") from None


def _letter(where: str, value: Any) -> str:
    if not isinstance(value, str) or len(value) != 1 or value.upper() not in "ABCUVW":
        raise InputError(f"{where}: rotary letter expects one of A, B, C, U, V, W; "
                         f"found {_shown(value)}")
    return value.upper()


def builtin_profiles() -> dict[str, Path]:
    """The machine profiles shipped with printability, by name."""
    return {p.stem: p for p in sorted(_DATA.glob("*.toml"))}


#: Largest machine profile read, bytes.
MAX_PROFILE_SIZE = 1 << 20


def load_machine_file(path: str | Path) -> Machine:
    """Read a machine profile from a TOML file (see the shipped examples)."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a FIFO would block, /dev/zero never end
        raise PrintabilityOSError(f"{path}: not a regular file (expected a machine profile, a "
                                  "TOML file)")
    try:
        with path.open("rb") as fh:
            data = fh.read(MAX_PROFILE_SIZE + 1)
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read machine profile ({exc.strerror})") from None
    if len(data) > MAX_PROFILE_SIZE:
        raise FileFormatError(path, f"a machine profile is expected to be at most "
                              f"{MAX_PROFILE_SIZE >> 10} KiB (a TOML file of a few tables)")
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise FileFormatError(path, "expected a UTF-8 TOML text file; found binary data") from None
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(path, f"not valid TOML ({exc})") from None
    return _from_profile(doc, str(path), str(path))


def parse_machine(spec: str | Machine) -> Machine:
    """Parse a machine SPEC: ``xy``, ``ttr[:min=,max=,step=,letter=]``, a built-in profile
    name (see :func:`builtin_profiles`) or a TOML file path.

    Raises
    ------
    UnknownOptionError, InputError, FileFormatError, PrintabilityOSError
    """
    if isinstance(spec, Machine):
        return spec
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"machine spec must be a non-empty string such as 'xy' or 'ttr'; "
                         f"found {spec!r}")
    text = spec.strip()
    if text.lower().endswith(".toml") or "/" in text or "\\" in text:
        return load_machine_file(text)
    head, _, rest = text.partition(":")
    profiles = builtin_profiles()
    if head.lower() not in MACHINE_KINDS.choices and head in profiles and not rest:
        return load_machine_file(profiles[head])
    if head.lower() not in ("xy", "ttr"):
        # (a profile named like a kind, ttr.toml, is reached by its path, not its name)
        choices = ", ".join(["xy", "ttr", *(n for n in profiles if n not in ("xy", "ttr")),
                             "FILE.toml"])
        raise InputError(f"unknown machine {_shown(head)}; expected one of: {choices}")
    kind = head.lower()
    params: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or key.strip().lower() not in ("min", "max", "step", "letter"):
            raise InputError(f"machine spec {_shown(text)}: expected min=, max=, step= or letter=; "
                             f"found {_shown(item)}")
        params[key.strip().lower()] = value.strip()
    if kind == "xy":
        if params:
            raise InputError(f"machine spec {_shown(text)}: an xy machine takes no parameters")
        return Machine(name="xy", kind="xy", spec=text, bed=DEFAULT_BED)
    nums = {}
    for key in ("min", "max", "step"):
        if key in params:
            try:
                nums[key] = float(params[key])
            except ValueError:
                raise InputError(f"machine spec {_shown(text)}: {key}= expects a number of "
                                 f"degrees; found {_shown(params[key])}") from None
    lo, hi = nums.get("min", -180.0), nums.get("max", 180.0)
    step = nums.get("step", DEFAULT_TTR_STEP)
    where = f"machine spec {_shown(text)}"
    _rotary_range(where, lo, hi, step)
    letter = _letter(where, params["letter"]) if "letter" in params else "C"
    full = hi - lo >= 360.0 - 1e-9
    return Machine(name="ttr", kind="ttr", spec=text, angle_min=lo, angle_max=hi,
                   angle_step=step, rotary_letter=letter, bed=DEFAULT_BED,
                   rotary=RotaryAxis(letter=letter, min_angle=-math.inf if full else lo,
                                     max_angle=math.inf if full else hi))
