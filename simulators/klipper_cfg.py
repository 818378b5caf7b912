"""The ``printer.cfg`` of Klipper's batch mode: a cartesian printer on the Linux-host MCU.

:func:`printer_cfg` writes it from a :class:`KlipperPrinter` (travel, toolhead and extruder
limits, the rotary nozzle axis as a ``[manual_stepper]``); the commands the runner
(:func:`simulators.klipper_batch.run_klipper`) sends before the file ride in comments of the
config, which Klipper ignores, and :func:`cfg_preamble` reads them back.

This module imports nothing from the project (it is a test and benchmark instrument).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any

__all__ = ["AXIS_TAG", "PREAMBLE_TAG", "START_END_MACROS", "KlipperPrinter", "cfg_preamble",
           "printer_cfg"]

#: Empty macros for the start/end macros slicer profiles for Klipper call; pass as
#: ``printer_cfg(extra=START_END_MACROS)`` when a file's own would otherwise be unknown.
START_END_MACROS = """
[gcode_macro START_PRINT]
gcode:
  G90

[gcode_macro END_PRINT]
gcode:
  M400

[gcode_macro PRINT_START]
gcode:
  G90

[gcode_macro PRINT_END]
gcode:
  M400
"""

#: The comment that carries a command the runner sends before the file.
PREAMBLE_TAG = "# printability-preamble:"
#: The comment that carries the rotary axis's registration (``MANUAL_STEPPER ...``).
AXIS_TAG = "# printability-axis:"


def _fmt(v: float) -> str:
    return f"{v:.6g}"


@dataclass(frozen=True)
class KlipperPrinter:
    """The printer a batch-mode ``printer.cfg`` describes (:func:`printer_cfg`).

    Attributes
    ----------
    rotary_letter : str or None
        G-code letter of the rotary nozzle axis (a ``[manual_stepper]`` named after it in lower
        case), or None for none. Not one of ``XYZEFN``.
    bed : (xmin, xmax, ymin, ymax)
        Travel limits of X and Y, mm; moves outside are ``Move out of range``.
    z_max : float
        Upper Z limit, mm (the lower one is 0).
    start_position : (x, y, z) or None
        Where the toolhead is taken to be, homed, when the file starts (mm; the runner sends
        ``SET_KINEMATIC_POSITION``). None: nothing is homed, the file must home (G28) first or
        its moves fail with ``Must home axis first``.
    max_velocity, max_accel : float
        Toolhead limits, mm/s and mm/s² (``[printer]``).
    square_corner_velocity : float
        Speed through a 90° corner, mm/s (Klipper's junction deviation).
    minimum_cruise_ratio : float
        Klipper's ``minimum_cruise_ratio`` (its default 0.5; 0 gives plain trapezoids).
    max_z_velocity, max_z_accel : float
        Z limits, mm/s and mm/s².
    nozzle_diameter, filament_diameter : float
        Extruder geometry, mm (they set Klipper's extrusion limits).
    max_extrude_cross_section : float or None
        Largest extrusion cross-section, mm², before ``Move exceeds maximum extrusion`` (None:
        Klipper's default, 4·nozzle_diameter²).
    max_extrude_only_distance : float
        Longest extrude-only move, mm of filament.
    rotary_velocity, rotary_accel : float
        The rotary axis's limits, degrees/s and degrees/s² (``LIMIT_VELOCITY``/``LIMIT_ACCEL``
        and the stepper's own ``velocity``/``accel``).
    rotary_corner_velocity : float
        ``INSTANTANEOUS_CORNER_VELOCITY``, degrees/s: a junction between two moves whose
        degrees-per-mm differ by r is limited to this / r mm/s (Klipper's default 1).
    rotary_range : (min, max) or None
        Rotary travel limits, degrees (None: unlimited, a nozzle turning freely).
    rotary_steps_per_turn : int
        Microsteps per 360° (3200: a 200-step motor at 16 microsteps, direct drive).
    arc_resolution : float or None
        ``[gcode_arcs]`` segment length, mm (None: no G2/G3 support, they are unknown commands).
    slicer_sections : bool
        Add ``[exclude_object]`` and ``[display_status]`` (EXCLUDE_OBJECT_*, M73, M117), which
        slicer profiles for Klipper use.
    extra : str
        More config text appended (macros, e.g. :data:`START_END_MACROS`).
    """

    rotary_letter: str | None = "C"
    bed: tuple[float, float, float, float] = (0.0, 250.0, 0.0, 210.0)
    z_max: float = 220.0
    start_position: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
    max_velocity: float = 300.0
    max_accel: float = 3000.0
    square_corner_velocity: float = 5.0
    minimum_cruise_ratio: float = 0.5
    max_z_velocity: float = 15.0
    max_z_accel: float = 300.0
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    max_extrude_cross_section: float | None = None
    max_extrude_only_distance: float = 50.0
    rotary_velocity: float = 720.0
    rotary_accel: float = 7200.0
    rotary_corner_velocity: float = 1.0
    rotary_range: tuple[float, float] | None = None
    rotary_steps_per_turn: int = 3200
    arc_resolution: float | None = 1.0
    slicer_sections: bool = True
    extra: str = ""


def printer_cfg(printer: KlipperPrinter | None = None, /, **settings: Any) -> str:
    """A Klipper ``printer.cfg`` for a cartesian printer on the Linux-host MCU, for batch mode.

    Parameters
    ----------
    printer : KlipperPrinter or None
        The printer (None: ``KlipperPrinter()``).
    **settings
        :class:`KlipperPrinter` fields that override it: ``printer_cfg(bed=(0, 200, 0, 200),
        z_max=180.0)``.

    Returns
    -------
    str
        The config. It carries the commands the runner sends before the file as
        ``# printability-preamble:`` comments, which Klipper ignores.
    """
    p = replace(printer or KlipperPrinter(), **settings)
    rotary_letter = p.rotary_letter
    if rotary_letter is not None:
        rotary_letter = rotary_letter.upper()
        if len(rotary_letter) != 1 or not rotary_letter.isalpha() or rotary_letter in "XYZEFN":
            raise ValueError(f"rotary_letter must be one letter other than XYZEFN, got "
                             f"{rotary_letter!r}")
    # Linux MCU pin names: gpio<N> (one use each) and analog0..7 for the thermistors
    pins = iter(f"gpio{i}" for i in range(1, 64))
    out = [*_toolhead_sections(p, pins), *_extruder_sections(p, pins)]
    # SET_KINEMATIC_POSITION, for start_position
    out.append("[force_move]\nenable_force_move: True\n\n")
    if p.arc_resolution is not None:
        out.append(f"[gcode_arcs]\nresolution: {_fmt(p.arc_resolution)}\n\n")
    if p.slicer_sections:
        out.append("[exclude_object]\n\n[display_status]\n\n")
    preamble = []
    if p.start_position is not None:
        x, y, z = p.start_position
        preamble.append(f"SET_KINEMATIC_POSITION X={_fmt(x)} Y={_fmt(y)} Z={_fmt(z)}")
    if rotary_letter is not None:
        out.extend(_rotary_sections(p, rotary_letter, pins))
    out.extend(f"{PREAMBLE_TAG} {cmd}\n" for cmd in preamble)
    if p.extra:
        out.append("\n" + p.extra.strip("\n") + "\n")
    return "".join(out)


def _toolhead_sections(p: KlipperPrinter, pins: Iterator[str]) -> list[str]:
    """The MCU, ``[printer]`` and the X, Y, Z steppers."""
    xmin, xmax, ymin, ymax = p.bed

    def stepper(name: str, rotation_distance: float, lo: float, hi: float, endstop: float,
                extra_lines: str = "") -> str:
        return (f"[stepper_{name}]\nstep_pin: {next(pins)}\ndir_pin: {next(pins)}\n"
                f"enable_pin: !{next(pins)}\nmicrosteps: 16\n"
                f"rotation_distance: {_fmt(rotation_distance)}\nendstop_pin: ^{next(pins)}\n"
                f"position_endstop: {_fmt(endstop)}\nposition_min: {_fmt(lo)}\n"
                f"position_max: {_fmt(hi)}\nhoming_speed: 50\n{extra_lines}\n")

    return [
        "# Klipper batch-mode config written by simulators/klipper_batch.printer_cfg\n",
        "[mcu]\nserial: /tmp/klipper_host_mcu\n\n",
        f"[printer]\nkinematics: cartesian\nmax_velocity: {_fmt(p.max_velocity)}\n"
        f"max_accel: {_fmt(p.max_accel)}\n"
        f"square_corner_velocity: {_fmt(p.square_corner_velocity)}\n"
        f"minimum_cruise_ratio: {_fmt(p.minimum_cruise_ratio)}\n"
        f"max_z_velocity: {_fmt(p.max_z_velocity)}\nmax_z_accel: {_fmt(p.max_z_accel)}\n\n",
        stepper("x", 40, xmin, xmax, xmin),
        stepper("y", 40, ymin, ymax, ymin),
        stepper("z", 8, 0, p.z_max, 0, "homing_speed: 10\n"),
    ]


def _extruder_sections(p: KlipperPrinter, pins: Iterator[str]) -> list[str]:
    """The extruder, the bed heater and the fan (batch mode has no temperatures: the heaters
    only have to be valid ones)."""
    cross = ("" if p.max_extrude_cross_section is None
             else f"max_extrude_cross_section: {_fmt(p.max_extrude_cross_section)}\n")
    return [
        f"[extruder]\nstep_pin: {next(pins)}\ndir_pin: {next(pins)}\nenable_pin: !{next(pins)}\n"
        f"microsteps: 16\nrotation_distance: 33.5\nnozzle_diameter: {_fmt(p.nozzle_diameter)}\n"
        f"filament_diameter: {_fmt(p.filament_diameter)}\n{cross}"
        f"max_extrude_only_distance: {_fmt(p.max_extrude_only_distance)}\n"
        f"heater_pin: {next(pins)}\nsensor_type: EPCOS 100K B57560G104F\nsensor_pin: analog0\n"
        "control: watermark\nmin_temp: 0\nmax_temp: 300\n\n",
        f"[heater_bed]\nheater_pin: {next(pins)}\nsensor_type: EPCOS 100K B57560G104F\n"
        "sensor_pin: analog1\ncontrol: watermark\nmin_temp: 0\nmax_temp: 130\n\n",
        f"[fan]\npin: {next(pins)}\n\n",
    ]


def _rotary_sections(p: KlipperPrinter, letter: str, pins: Iterator[str]) -> list[str]:
    """The rotary axis's ``[manual_stepper]``, and its registration as a comment."""
    name = letter.lower()
    limits = ("" if p.rotary_range is None else
              f"position_min: {_fmt(p.rotary_range[0])}\n"
              f"position_max: {_fmt(p.rotary_range[1])}\n")
    register = (f"MANUAL_STEPPER STEPPER={name} GCODE_AXIS={letter} "
                f"LIMIT_VELOCITY={_fmt(p.rotary_velocity)} LIMIT_ACCEL={_fmt(p.rotary_accel)} "
                f"INSTANTANEOUS_CORNER_VELOCITY={_fmt(p.rotary_corner_velocity)}")
    return [
        f"[manual_stepper {name}]\nstep_pin: {next(pins)}\ndir_pin: {next(pins)}\n"
        f"enable_pin: !{next(pins)}\nmicrosteps: 16\n"
        # rotation_distance in degrees: positions and speeds of the axis are in degrees
        f"rotation_distance: 360\nfull_steps_per_rotation: {p.rotary_steps_per_turn // 16}\n"
        f"velocity: {_fmt(p.rotary_velocity)}\naccel: {_fmt(p.rotary_accel)}\n{limits}\n",
        f"{AXIS_TAG} {register}\n",
    ]


def cfg_preamble(cfg: str) -> tuple[list[str], list[str]]:
    """(axis registrations, other preamble commands) carried in ``cfg``'s comments."""
    axes, other = [], []
    for line in cfg.splitlines():
        s = line.strip()
        if s.startswith(AXIS_TAG):
            axes.append(s[len(AXIS_TAG):].strip())
        elif s.startswith(PREAMBLE_TAG):
            other.append(s[len(PREAMBLE_TAG):].strip())
    return axes, other
