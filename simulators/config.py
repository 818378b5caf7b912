"""Configuration of the virtual printer: firmware profiles and the simulator setup.

A :class:`FirmwareProfile` holds what differs between firmwares (protocol
strictness, reply formats, buffer sizes, motion and thermal constants). The
three built-in profiles (:data:`printability.options.FIRMWARE_PROFILES`) start
from Marlin 2.1's defaults (``Configuration.h`` / ``Configuration_adv.h``:
BUFSIZE 4, BLOCK_BUFFER_SIZE 16, RX_BUFFER_SIZE 128, MAX_CMD_SIZE 96,
DEFAULT_KEEPALIVE_INTERVAL 2 s, TEMP_WINDOW 1 °C, TEMP_RESIDENCY_TIME 10 s,
junction deviation 0.013 mm). A machine profile's ``[firmware]`` table may
override the buffer and motion keys (see ``printability/data/machines/ttr.toml``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from printability.base.errors import InputError
from printability.base.options import ENDSTOP_POLICIES, FIRMWARE_PROFILES, SIM_CLOCKS
from printability.layers import LayerStack
from printability.machine import Machine, builtin_profiles, load_machine_file, parse_machine
from printability.nozzle import Nozzle, parse_nozzle
from simulators.faults import FaultPlan

__all__ = ["FirmwareProfile", "SimConfig", "firmware_profile", "make_config", "resolve_machine"]


@dataclass(frozen=True)
class FirmwareProfile:
    """What a host sees of one firmware, and the constants of its machine model.

    Attributes
    ----------
    name
        Key in :data:`printability.options.FIRMWARE_PROFILES`.
    firmware_name
        Reported by M115.
    checksums
        Verify ``N<n> … *<xor>`` and ask for resends (False: Klipper-like,
        line numbers and checksums are stripped and ignored).
    advanced_ok
        Reply ``ok N<n> P<planner free> B<buffer free>``.
    ok_after_resend
        Send ``ok`` after ``Resend: <n>`` (Marlin does; some firmwares do not).
    banner
        Lines sent on connect and after a reset.
    endstops
        ``clamp`` (Marlin) or ``error`` (Klipper), see
        :data:`printability.options.ENDSTOP_POLICIES`.
    rx_buffer
        Serial receive ring, bytes.
    command_buffer
        Command queue, lines (Marlin BUFSIZE).
    planner_buffer
        Planner, blocks (Marlin BLOCK_BUFFER_SIZE).
    max_line
        Longest command kept, characters (longer lines are truncated, as
        Marlin's MAX_CMD_SIZE − 1).
    rx_overflow_drops
        True: bytes beyond a full receive ring are lost (AVR + UART bridge);
        False: the sender is held back (native USB flow control).
    busy_interval
        Seconds between ``echo:busy: processing`` while a command blocks.
    acceleration, rotary_acceleration
        mm/s², deg/s².
    max_feed_xy, max_feed_z, max_feed_e, max_feed_rotary
        mm/s (deg/s for the rotary axis).
    junction_deviation
        mm (Marlin's JD model of cornering speed).
    arc_segment, arc_min_segments
        Marlin's arc linearisation: segments of at most ``arc_segment`` mm and
        at least ``arc_min_segments`` per full circle.
    z_max
        Top of the Z travel, mm.
    homing_time
        Seconds a G28 takes.
    ambient, hotend_tau, bed_tau, temp_window, hotend_residency, bed_residency
        First-order thermal model: °C, time constants in s, the window in °C
        within which a wait counts as reached, and how long it must stay there (s).
    steps_per_unit
        (x, y, z, rotary, e) steps per mm or per degree, for M114's ``Count``.
    """

    name: str = "marlin"
    firmware_name: str = "Marlin 2.1.2.4 (printability simulator)"
    checksums: bool = True
    advanced_ok: bool = False
    ok_after_resend: bool = True
    banner: tuple[str, ...] = ("start", "echo:Marlin 2.1.2.4", "echo: Last Updated: 2024-06-01",
                               "echo:Free Memory: 4096  PlannerBufferBytes: 1152")
    unknown_format: str = 'echo:Unknown command: "{}"'
    endstops: str = "clamp"
    rx_buffer: int = 128
    command_buffer: int = 4
    planner_buffer: int = 16
    max_line: int = 96
    rx_overflow_drops: bool = False
    busy_interval: float = 2.0
    acceleration: float = 1000.0
    rotary_acceleration: float = 3000.0
    max_feed_xy: float = 300.0
    max_feed_z: float = 12.0
    max_feed_e: float = 120.0
    max_feed_rotary: float = 720.0
    junction_deviation: float = 0.013
    arc_segment: float = 1.0
    arc_min_segments: int = 72
    z_max: float = 250.0
    homing_time: float = 6.0
    ambient: float = 22.0
    hotend_tau: float = 25.0
    bed_tau: float = 60.0
    temp_window: float = 1.0
    hotend_residency: float = 10.0
    bed_residency: float = 10.0
    steps_per_unit: tuple[float, float, float, float, float] = (80.0, 80.0, 400.0, 10.0, 93.0)

    def __post_init__(self) -> None:
        FIRMWARE_PROFILES.check(self.name)
        ENDSTOP_POLICIES.check(self.endstops)
        for key in ("rx_buffer", "command_buffer", "planner_buffer", "max_line",
                    "arc_min_segments"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"firmware profile {self.name}: {key} must be a positive "
                                 f"integer; found {v!r}")
        for key in ("busy_interval", "acceleration", "rotary_acceleration", "max_feed_xy",
                    "max_feed_z", "max_feed_e", "max_feed_rotary", "junction_deviation",
                    "arc_segment", "z_max", "hotend_tau", "bed_tau", "temp_window"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                    math.isfinite(v) and v > 0):
                raise InputError(f"firmware profile {self.name}: {key} must be a positive "
                                 f"number; found {v!r}")
        if self.rx_buffer < self.max_line:
            raise InputError(f"firmware profile {self.name}: rx_buffer ({self.rx_buffer} bytes) "
                             f"must hold at least one full line (max_line = {self.max_line})")


_KLIPPER = dict(
    name="klipper", firmware_name="v0.12.0-printability-simulator", checksums=False,
    advanced_ok=False, ok_after_resend=False, banner=(),
    unknown_format='// Unknown command:"{}"', endstops="error", rx_buffer=4096,
    command_buffer=64, planner_buffer=64, max_line=4096, acceleration=3000.0,
    junction_deviation=0.02,
)
_BUILTIN: dict[str, dict[str, Any]] = {
    "marlin": {},
    "marlin-advanced": {"name": "marlin-advanced", "advanced_ok": True},
    "klipper": _KLIPPER,
}
# Keys a machine profile's [firmware] table may override.
_PROFILE_KEYS = {f.name for f in fields(FirmwareProfile)} - {"name", "banner", "unknown_format",
                                                              "steps_per_unit"}


def firmware_profile(name: str = "marlin", *, machine: Machine | None = None,
                     **overrides: Any) -> FirmwareProfile:
    """A built-in firmware profile, with the machine's ``[firmware]`` keys and overrides applied.

    Parameters
    ----------
    name
        One of :data:`printability.options.FIRMWARE_PROFILES`.
    machine
        Its profile's ``[firmware]`` table may set buffer sizes, accelerations,
        feed limits... (any :class:`FirmwareProfile` field but the name and texts).
    **overrides
        Field values that win over both.
    """
    key = FIRMWARE_PROFILES.check(name)
    kw = dict(_BUILTIN[key])
    if machine is not None:
        if machine.rotary is not None:
            # the axis the G-code is planned for ([rotary]), unless [firmware] says otherwise
            kw["max_feed_rotary"] = machine.rotary.max_speed
            kw["rotary_acceleration"] = machine.rotary.acceleration
        fw = machine.profile.get("firmware", {}) if machine.profile else {}
        for k, v in fw.items():
            if k in ("flavor", "feed_policy"):
                continue
            if k not in _PROFILE_KEYS:
                raise InputError(f"machine profile {machine.name}: unknown [firmware] key {k!r}; "
                                 f"expected flavor, feed_policy or one of: "
                                 f"{', '.join(sorted(_PROFILE_KEYS))}")
            kw[k] = v
    for k in overrides:
        if k not in _PROFILE_KEYS | {"banner", "unknown_format", "steps_per_unit"}:
            raise InputError(f"unknown firmware setting {k!r}; expected one of: "
                             f"{', '.join(sorted(_PROFILE_KEYS))}")
    kw.update(overrides)
    return FirmwareProfile(**kw)


@dataclass(frozen=True)
class SimConfig:
    """Everything a simulator instance needs.

    Attributes
    ----------
    firmware
        The firmware profile.
    machine
        T-T-R (or XY) machine: rotary letter and limits, bed, feed policy.
    nozzle
        The footprint deposited by extruding moves.
    clock
        ``sim`` or ``real`` (:data:`printability.options.SIM_CLOCKS`).
    baud
        Wire pacing in bits per second (10 bits per byte), or None for none.
    faults
        Faults to inject.
    record
        Path of the deposition record written on close, or None.
    target
        Layers the part should have; the record reports MMC violations and coverage.
    chord_tolerance
        Largest sideways error when a turning nozzle's sweep is subdivided, mm.
    quad_segs
        Segments per quarter circle of a round/elliptic footprint outline.
    """

    firmware: FirmwareProfile = field(default_factory=FirmwareProfile)
    machine: Machine = field(default_factory=lambda: resolve_machine("ttr"))
    nozzle: Nozzle = field(default_factory=lambda: parse_nozzle("circle:d=0.4"))
    clock: str = "sim"
    baud: int | None = None
    faults: FaultPlan = field(default_factory=FaultPlan)
    record: str | None = None
    target: LayerStack | None = None
    chord_tolerance: float = 0.005
    quad_segs: int = 8

    def __post_init__(self) -> None:
        SIM_CLOCKS.check(self.clock)
        if self.baud is not None and (isinstance(self.baud, bool) or self.baud <= 0):
            raise InputError(f"baud must be a positive number of bits per second; "
                             f"found {self.baud!r}")
        if not (self.chord_tolerance > 0):
            raise InputError(f"chord_tolerance must be a positive length in mm; "
                             f"found {self.chord_tolerance!r}")


def resolve_machine(spec: str | Machine) -> Machine:
    """A machine SPEC; a built-in profile name (``ttr``, ``polar``...) loads the shipped TOML
    profile, which carries the bed and firmware settings a printer needs."""
    if isinstance(spec, str) and spec.strip() in builtin_profiles():
        return load_machine_file(builtin_profiles()[spec.strip()])
    return parse_machine(spec)


def make_config(*, profile: str = "marlin", machine: str | Machine = "ttr",
                nozzle: str | Nozzle = "circle:d=0.4", clock: str = "sim",
                baud: int | None = None, faults: str | FaultPlan | None = None,
                seed: int = 0, record: str | None = None, target: LayerStack | None = None,
                firmware: Mapping[str, Any] | None = None) -> SimConfig:
    """Build a :class:`SimConfig` from the string options the CLI and URLs use.

    Parameters
    ----------
    profile
        Firmware profile name.
    machine, nozzle
        SPECs (see :func:`printability.machine.parse_machine`, :func:`parse_nozzle`).
    faults
        A fault spec (see :func:`simulators.faults.parse_faults`) or a plan.
    seed
        Seed of the random faults.
    firmware
        Firmware overrides (buffer sizes...).
    """
    m = resolve_machine(machine)
    fw = firmware_profile(profile, machine=m, **dict(firmware or {}))
    if isinstance(faults, FaultPlan):
        plan = faults if faults.seed == seed or seed == 0 else replace(faults, seed=seed)
    else:
        plan = FaultPlan.parse(faults or "", seed=seed)
    return SimConfig(firmware=fw, machine=m, nozzle=parse_nozzle(nozzle),
                     clock=SIM_CLOCKS.check(clock), baud=baud, faults=plan, record=record,
                     target=target)
