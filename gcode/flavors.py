"""Firmware flavors: what each firmware does with the words printability writes.

One class per firmware, each owning everything that differs between them for a
machine whose nozzle turns on a rotary axis (T-T-R): how the axis is declared
or registered and its position set at the start of a file, what F means on a
move that turns, which commands may carry the rotary word, whether G93
inverse-time feed exists, the default start and end G-code of a generated
file, and how the reader treats ``G90``/``G91`` and E (:attr:`Flavor.reader_code`).
The writer, the post-processor, ``generate``, the simulator and the tests read
these objects; nothing else compares flavor names.

What each firmware does was checked in its sources and documentation
(``docs/design.md`` §3 has the table; Klipper ``klippy/extras/manual_stepper.py``
and ``klippy/toolhead.py`` of v0.13, Marlin 2.1 ``Configuration.h`` ``AXIS4_NAME`` /
``AXIS4_ROTATES`` and ``G92``/``M114``, RepRapFirmware 3 ``M584 … R1 S1``):

* **Feed rate.** Marlin ≥ 2.1, Klipper and RepRapFirmware 3 with a rotational
  axis follow the RS274/LinuxCNC rule: on a move with X, Y or Z motion, F is
  the speed of the XYZ motion and the rotary axis follows in proportion; on a
  move with *no* XYZ motion, F is in **degrees per minute**. A rotation-only
  move that carried no F of its own would inherit the XY feed (e.g. F1200 =
  20 °/s): every such move must carry its own F and the next XY move must
  restore the XY feed.
* **Klipper** registers a ``[manual_stepper]`` as a G-code axis at run time
  (``MANUAL_STEPPER STEPPER=c GCODE_AXIS=C LIMIT_VELOCITY= LIMIT_ACCEL=
  INSTANTANEOUS_CORNER_VELOCITY=``). Until then a ``C`` word is dropped without
  a message; ``G92`` handles X Y Z E only (``G92 C0`` is silently ignored), the
  position is set with ``MANUAL_STEPPER STEPPER=c SET_POSITION=`` while the
  axis is *not* registered; G2/G3 take no rotary word and G93 does not exist.
  A move that has no XYZ motion never blends with its neighbours (the
  toolhead comes to a stop before and after it), and the junction between
  two moves whose degrees-per-mm ratios differ is limited to
  ``INSTANTANEOUS_CORNER_VELOCITY / |Δratio|``.
* **Marlin 2.1** declares the axis at compile time (``AXIS4_NAME 'C'``,
  ``AXIS4_ROTATES``, steps per degree by ``M92``); ``G92 C0`` sets it; ``M114``
  reports it and ``M115`` reports ``AXIS_COUNT``.
* **RepRapFirmware 3** declares it in ``config.g`` (``M584 C<driver> R1 S1``:
  rotational, and S1 so that F is the XYZ speed); ``G92 C0`` sets it.
* **generic** (RS274 "all axes Euclidean"): the firmware moves at F along
  √(ΔX² + ΔY² + ΔZ² + ΔC²), degrees counted as millimetres, so F is scaled to
  keep the XY speed (:func:`gcode.rotary.feed_for_move`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

__all__ = [
    "FLAVORS",
    "Flavor",
    "GenericFlavor",
    "KlipperFlavor",
    "MarlinFlavor",
    "PlannerLimits",
    "RepRapFlavor",
    "RotaryAxis",
    "flavor_named",
]


@dataclass(frozen=True)
class RotaryAxis:
    """The rotary axis turning the nozzle, as the firmware knows it.

    Attributes
    ----------
    letter
        G-code word of the axis (ISO 841: C turns about Z).
    min_angle, max_angle
        Travel limits, degrees (±inf for a slip-ring head).
    max_speed
        Top angular speed, °/s: the F of a rotation-only move is 60 × this
        (degrees per minute).
    acceleration
        Angular acceleration, °/s².
    corner_velocity
        The change of angular speed the axis takes without slowing, °/s
        (Klipper's ``INSTANTANEOUS_CORNER_VELOCITY``, Marlin's jerk).
    stepper
        Name of the Klipper ``[manual_stepper NAME]`` section that drives it.
    """

    letter: str = "C"
    min_angle: float = -math.inf
    max_angle: float = math.inf
    max_speed: float = 360.0
    acceleration: float = 3600.0
    corner_velocity: float = 30.0
    stepper: str = "c"

    def __post_init__(self) -> None:
        if len(self.letter) != 1 or self.letter.upper() not in "ABCUVW":
            raise ValueError(f"rotary letter must be one of A B C U V W; got {self.letter!r}")
        for key in ("max_speed", "acceleration"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"rotary {key} must be a positive finite number; got {v!r}")
        if not (math.isfinite(self.corner_velocity) and self.corner_velocity >= 0):
            raise ValueError("rotary corner_velocity must be a finite number >= 0; got "
                             f"{self.corner_velocity!r}")
        if math.isnan(self.min_angle) or math.isnan(self.max_angle) or \
                self.max_angle < self.min_angle:
            raise ValueError(f"rotary limits must satisfy min <= max; got [{self.min_angle}, "
                             f"{self.max_angle}]")
        if not self.stepper.replace("_", "").isalnum():
            raise ValueError(f"Klipper stepper name must be letters, digits or _; got "
                             f"{self.stepper!r}")

    @property
    def rotation_feed(self) -> float:
        """F of a rotation-only move, degrees per minute."""
        return 60.0 * self.max_speed


@dataclass(frozen=True)
class PlannerLimits:
    """The firmware's motion limits (Klipper's ``[printer]``, ``[extruder]``, ``gcode_arcs``).

    Attributes
    ----------
    max_velocity, max_accel
        mm/s, mm/s² (the file's M204 / SET_VELOCITY_LIMIT change the acceleration as it goes).
    square_corner_velocity
        mm/s; the junction deviation is ``scv² (√2 − 1) / max_accel``.
    minimum_cruise_ratio
        Share of a move's length kept at cruise speed when it can (Klipper ≥ 0.12).
    max_z_velocity, max_z_accel
        mm/s, mm/s².
    nozzle_diameter, filament_diameter
        mm: the extruder's default limits (4·d² of cross-section).
    extrude_only_velocity, extrude_only_accel
        mm/s, mm/s² of filament for E-only and retraction moves; None: Klipper's defaults.
    extruder_corner_velocity
        mm/s of filament the extruder's speed may jump at a junction.
    arc_resolution
        mm per arc segment.
    """

    max_velocity: float = 300.0
    max_accel: float = 3000.0
    square_corner_velocity: float = 5.0
    minimum_cruise_ratio: float = 0.5
    max_z_velocity: float = 15.0
    max_z_accel: float = 300.0
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    extrude_only_velocity: float | None = None
    extrude_only_accel: float | None = None
    extruder_corner_velocity: float = 1.0
    arc_resolution: float = 1.0

    def __post_init__(self) -> None:
        for key, value in self.__dict__.items():
            if value is None:
                continue
            if not (math.isfinite(value) and value >= 0) or (
                    value == 0 and key not in ("minimum_cruise_ratio",
                                               "extruder_corner_velocity",
                                               "square_corner_velocity")):
                raise ValueError(f"planner limit {key} must be a positive finite number; "
                                 f"got {value!r}")
        if self.minimum_cruise_ratio >= 1:
            raise ValueError("planner limit minimum_cruise_ratio must be below 1; got "
                             f"{self.minimum_cruise_ratio!r}")

    def extruder_limits(self) -> tuple[float, float]:
        """(velocity, accel) of extrude-only moves, as Klipper defaults them."""
        ratio = 4.0 * self.nozzle_diameter ** 2 / (math.pi * (self.filament_diameter / 2) ** 2)
        v = self.extrude_only_velocity
        a = self.extrude_only_accel
        return (self.max_velocity * ratio if v is None else v,
                self.max_accel * ratio if a is None else a)


_START = ("M140 S{first_layer_bed}", "M104 S{first_layer_nozzle}", "G28",
          "M190 S{first_layer_bed}", "M109 S{first_layer_nozzle}")
_END = ("M104 S0", "M140 S0", "G91", "G1 Z5 F600", "G90", "M84")


class Flavor:
    """A firmware's G-code flavor (subclasses are the flavors; instances are stateless).

    Attributes
    ----------
    name, description
        Registry name and a one-line description.
    reader_code
        How the compiled reader treats G90/G91 and E (0: G90/G91 also set E
        absolute/relative, as Marlin and RS274; 1: they leave an M83 alone,
        as Klipper and RepRapFirmware).
    feed_policy
        What F means on a move that also turns: ``"xy"`` (the XYZ speed) or
        ``"euclidean"`` (speed along the Euclidean length, degrees as mm).
    inverse_time
        True when the firmware has G93 inverse-time feed.
    rotary_on_g92
        True when ``G92 C…`` sets the rotary position.
    """

    name: ClassVar[str]
    description: ClassVar[str]
    reader_code: ClassVar[int] = 0
    feed_policy: ClassVar[str] = "xy"
    inverse_time: ClassVar[bool] = False
    rotary_on_g92: ClassVar[bool] = True

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other)

    def __hash__(self) -> int:
        return hash(type(self))

    # ---------------------------------------------------------------- rotary axis
    def declare_rotary(self, axis: RotaryAxis) -> tuple[str, ...]:
        """Lines that make ``axis`` usable and call the nozzle's current orientation 0.

        Placed before the first rotary word of a file; each line ends with a
        comment saying what it does.
        """
        return (f"G92 {axis.letter}0 ; the nozzle's current orientation is angle 0",)

    def rotary_setup_note(self, axis: RotaryAxis) -> str:
        """One line for the file header: what the firmware's configuration must declare."""
        return f"the firmware must declare rotary axis {axis.letter}"

    def rotary_words_allowed(self, command: str) -> bool:
        """True when ``command`` (``"G1"``, ``"G2"``...) may carry the rotary word."""
        return command in ("G0", "G1") or (command == "G92" and self.rotary_on_g92)

    # ---------------------------------------------------------------- templates
    def start_gcode(self) -> tuple[str, ...]:
        """Default start G-code of a generated file (``{first_layer_bed}``... placeholders)."""
        return _START

    def end_gcode(self) -> tuple[str, ...]:
        """Default end G-code of a generated file."""
        return _END


class MarlinFlavor(Flavor):
    name = "marlin"
    description = ("Marlin 2.1 or newer with AXIS4_NAME 'C' and AXIS4_ROTATES (F is the XYZ "
                   "speed; degrees/min on a rotation-only move)")

    def rotary_setup_note(self, axis: RotaryAxis) -> str:
        return (f"Marlin 2.1 built with AXIS4_NAME '{axis.letter}' and AXIS4_ROTATES "
                "(M92 in steps per degree)")


class KlipperFlavor(Flavor):
    name = "klipper"
    description = ("Klipper with a [manual_stepper] registered as G-code axis C (F is the XYZ "
                   "speed; degrees/min on a rotation-only move; no G92 C)")
    reader_code = 1
    rotary_on_g92 = False

    def declare_rotary(self, axis: RotaryAxis) -> tuple[str, ...]:
        s = axis.stepper
        # SET_POSITION is refused while the stepper is a G-code axis: unregister first (a
        # no-op when it is not registered), set, then register with the axis's limits
        return (
            f"MANUAL_STEPPER STEPPER={s} GCODE_AXIS= ; unregister {axis.letter} if a macro "
            "registered it",
            f"MANUAL_STEPPER STEPPER={s} ENABLE=1",
            f"MANUAL_STEPPER STEPPER={s} SET_POSITION=0 ; the nozzle's current orientation "
            "is angle 0",
            f"MANUAL_STEPPER STEPPER={s} GCODE_AXIS={axis.letter} "
            f"LIMIT_VELOCITY={axis.max_speed:g} LIMIT_ACCEL={axis.acceleration:g} "
            f"INSTANTANEOUS_CORNER_VELOCITY={axis.corner_velocity:g}",
        )

    def rotary_setup_note(self, axis: RotaryAxis) -> str:
        return (f"Klipper: printer.cfg needs [manual_stepper {axis.stepper}] (rotation_distance "
                f"in degrees); this file registers it as G-code axis {axis.letter}")


class RepRapFlavor(Flavor):
    name = "reprap"
    description = ("RepRapFirmware 3 with M584 C<driver> R1 S1 in config.g (F is the XYZ speed; "
                   "degrees/min on a rotation-only move)")
    reader_code = 1

    def rotary_setup_note(self, axis: RotaryAxis) -> str:
        return (f"RepRapFirmware 3: config.g needs M584 {axis.letter}<driver> R1 S1 "
                "(rotational, F is the XYZ speed)")

    def start_gcode(self) -> tuple[str, ...]:
        return ("M140 S{first_layer_bed}", "G10 P0 S{first_layer_nozzle} R{first_layer_nozzle}",
                "T0", "G28", "M116")

    def end_gcode(self) -> tuple[str, ...]:
        return ("G10 P0 S0 R0", "M140 S0", "G91", "G1 Z5 F600", "G90", "M84")


class GenericFlavor(Flavor):
    name = "generic"
    description = ("generic RS274 firmware that treats every axis as Euclidean (degrees count "
                   "as mm in F)")
    reader_code = 0
    feed_policy = "euclidean"

    def rotary_setup_note(self, axis: RotaryAxis) -> str:
        return (f"generic firmware: axis {axis.letter} is moved as a linear axis in degrees; "
                "F is scaled to keep the XY speed")


FLAVORS: Mapping[str, Flavor] = MappingProxyType(
    {f.name: f for f in (MarlinFlavor(), KlipperFlavor(), RepRapFlavor(), GenericFlavor())})
"""Every flavor by name (the order of :data:`printability.options.FLAVORS`)."""


def flavor_named(name: str | Flavor) -> Flavor:
    """The flavor called ``name`` (a :class:`Flavor` is returned as is).

    Raises
    ------
    ValueError
        No such flavor; the message lists the known ones.
    """
    if isinstance(name, Flavor):
        return name
    key = str(name).strip().lower()
    try:
        return FLAVORS[key]
    except KeyError:
        raise ValueError(f"unknown G-code flavor {name!r}; expected one of: "
                         f"{', '.join(FLAVORS)}") from None
