"""Firmware profiles: what differs between the firmwares the virtual printer plays.

A :class:`FirmwareProfile` holds a firmware's protocol strictness, reply
formats, buffer sizes and motion and thermal constants, and its behaviour:
the commands it ignores, whether an emergency parser reads M112 as it
arrives, what it says when killed, to an unknown command, to M105 and M115.
:class:`FirmwareProfile` itself is Marlin 2.1 (``Configuration.h`` /
``Configuration_adv.h``: BUFSIZE 4, BLOCK_BUFFER_SIZE 16, RX_BUFFER_SIZE 128,
MAX_CMD_SIZE 96, DEFAULT_KEEPALIVE_INTERVAL 2 s, TEMP_WINDOW 1 °C,
TEMP_RESIDENCY_TIME 10 s, junction deviation 0.013 mm); another firmware is a
subclass with its own defaults and answers (:class:`KlipperProfile`), named in
the built-in table (:data:`printability.options.FIRMWARE_PROFILES` lists the
names). A machine profile's ``[firmware]`` table may override the buffer and
motion keys (see ``printability/data/machines/ttr.toml``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, ClassVar

from printability.base.errors import InputError
from printability.base.options import ENDSTOP_POLICIES, FIRMWARE_PROFILES
from printability.model.machine import Machine

if TYPE_CHECKING:
    from simulators.commands import Heater

__all__ = ["MARLIN_NOOP_CODES", "FirmwareProfile", "KlipperProfile", "firmware_profile"]

#: Commands Marlin accepts and (for the simulation) need no effect.
MARLIN_NOOP_CODES = frozenset({
    "M17", "M18", "M84", "M106", "M107", "M73", "M75", "M76", "M77", "M117", "M118", "M201",
    "M205", "M221", "M500", "M501", "M502", "M503", "M900", "M907", "M92", "M80", "M81",
    "M111", "M119", "M31", "M42", "M420", "M149", "M851", "M593", "M486", "M999", "G21",
    "G29", "G10", "G11", "M0", "M1", "M16", "M23", "M24", "M25", "M27", "M28", "M29", "M30",
    "M32", "M33", "M928", "M413", "M163", "M164", "M141", "M191", "M150", "M600",
    # M108 (break a heating wait: the host's cancel sends it raw; the emergency parser acts on
    # it); M113 and M21 are answered (simulators.commands)
    "M108",
})
# M115's Cap: lines, ADVANCED_OK aside (it follows the profile)
_MARLIN_CAPS = (
    ("SERIAL_XON_XOFF", 0), ("BINARY_FILE_TRANSFER", 0), ("EEPROM", 0), ("VOLUMETRIC", 1),
    ("AUTOREPORT_POS", 0), ("AUTOREPORT_TEMP", 1), ("PROGRESS", 0), ("PRINT_JOB", 1),
    ("AUTOLEVEL", 0), ("RUNOUT", 0), ("Z_PROBE", 0), ("LEVELING_DATA", 0),
    ("BUILD_PERCENT", 0), ("SOFTWARE_POWER", 0), ("TOGGLE_LIGHTS", 0),
    ("CASE_LIGHT_BRIGHTNESS", 0), ("EMERGENCY_PARSER", 1), ("HOST_ACTION_COMMANDS", 0),
    ("PROMPT_SUPPORT", 0), ("SDCARD", 1), ("REPEAT", 0), ("SD_WRITE", 0),
    ("AUTOREPORT_SD_STATUS", 0), ("LONG_FILENAME", 0), ("EXTENDED_M20", 0),
    ("THERMAL_PROTECTION", 1), ("MOTION_MODES", 0), ("ARCS", 1), ("BABYSTEPPING", 0),
    ("CHAMBER_TEMPERATURE", 0), ("COOLER_TEMPERATURE", 0), ("MEATPACK", 0),
    ("CONFIG_EXPORT", 0),
)
# Klipper's extended commands: a macro name (WORD_WORD...) or one of its own
_KLIPPER_MACROS = re.compile(r"^[A-Z][A-Z0-9]*_[A-Z0-9_]+\b|^(?:PAUSE|RESUME|CANCEL_PRINT|"
                             r"STATUS|RESTART|FIRMWARE_RESTART|SAVE_CONFIG)\b", re.IGNORECASE)


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

    Class attributes (a firmware's behaviour, set by its subclass):
    ``noop_codes`` (commands accepted with no effect), ``emergency_parser``
    (M112 and M108 act as the bytes arrive, before the line is queued),
    ``kill_message`` (said on M112); and the methods :meth:`unknown_reply`,
    :meth:`temperature_report` and :meth:`capabilities` (M115).
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

    # What the firmware does, beyond its constants (a new firmware overrides these in its
    # subclass): the commands it accepts and ignores, whether an emergency parser reads
    # M112/M108 as they arrive, what it says when killed.
    noop_codes: ClassVar[frozenset[str]] = MARLIN_NOOP_CODES
    emergency_parser: ClassVar[bool] = True
    kill_message: ClassVar[str] = "Error:Printer halted. kill() called!"

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

    def unknown_reply(self, text: str) -> str | None:
        """What the firmware says to the command ``text`` it does not know (None: nothing,
        it takes it)."""
        return self.unknown_format.format(text)

    def temperature_report(self, hotend: Heater, bed: Heater, t: float, *,
                           wait: bool = False) -> str:
        """The temperatures as M105 (after ``ok``), the auto-report and the heating waits
        (``wait``) say them at time ``t``, s."""
        text = (f" T:{hotend.temp(t):.2f} /{hotend.target:.2f} B:{bed.temp(t):.2f} "
                f"/{bed.target:.2f} @:{hotend.power(t)} B@:{bed.power(t)}")
        if wait:
            text += " W:?"
        return text

    def capabilities(self, machine: Machine, *, letter: str | None,
                     feed_policy: str) -> list[str]:
        """M115's reply: the firmware line, then the capabilities (Marlin's ``Cap:`` lines,
        and the rotary axis ``letter`` of ``machine`` when it has one)."""
        axes = 4 if letter else 3
        lines = [f"FIRMWARE_NAME:{self.firmware_name} SOURCE_CODE_URL:github.com/"
                 f"MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:{machine.name} "
                 f"KINEMATICS:Cartesian EXTRUDER_COUNT:1 AXIS_COUNT:{axes}"]
        caps = [*_MARLIN_CAPS, ("ADVANCED_OK", int(self.advanced_ok))]
        lines += [f"Cap:{k}:{v}" for k, v in caps]
        if letter:
            lo = "none" if machine.full_turn else f"{machine.angle_min:g}"
            hi = "none" if machine.full_turn else f"{machine.angle_max:g}"
            lines.append(f"Cap:ROTARY_AXIS:{letter}")
            lines.append(f"echo:Rotary axis {letter} (deg) min:{lo} max:{hi} "
                         f"feed_policy:{feed_policy}")
        return lines


@dataclass(frozen=True)
class KlipperProfile(FirmwareProfile):
    """Klipper as a host sees it over its pseudo-terminal: no line numbers nor checksums,
    no resend protocol, large buffers, extended (macro) commands, its own reply formats."""

    name: str = "klipper"
    firmware_name: str = "v0.12.0-printability-simulator"
    checksums: bool = False
    advanced_ok: bool = False
    ok_after_resend: bool = False
    banner: tuple[str, ...] = ()
    unknown_format: str = '// Unknown command:"{}"'
    endstops: str = "error"
    rx_buffer: int = 4096
    command_buffer: int = 64
    planner_buffer: int = 64
    max_line: int = 4096
    acceleration: float = 3000.0
    junction_deviation: float = 0.02

    # Klipper takes Marlin's M113 (keepalive) and M21 (SD card) as no-ops; M112 is read with
    # the line, there is no emergency parser
    noop_codes: ClassVar[frozenset[str]] = MARLIN_NOOP_CODES | {"M113", "M21"}
    emergency_parser: ClassVar[bool] = False
    kill_message: ClassVar[str] = "!! Shutdown due to M112 command"

    def unknown_reply(self, text: str) -> str | None:
        if _KLIPPER_MACROS.match(text):
            return None  # an extended command (macro): accepted
        return self.unknown_format.format(text.split(" ")[0].upper())

    def temperature_report(self, hotend: Heater, bed: Heater, t: float, *,
                           wait: bool = False) -> str:
        return (f" B:{bed.temp(t):.1f} /{bed.target:.1f} T0:{hotend.temp(t):.1f} "
                f"/{hotend.target:.1f}")

    def capabilities(self, machine: Machine, *, letter: str | None,
                     feed_policy: str) -> list[str]:
        return [f"FIRMWARE_NAME:Klipper FIRMWARE_VERSION:{self.firmware_name}"]


# The built-in profiles (printability.options.FIRMWARE_PROFILES): the type and its settings.
_BUILTIN: dict[str, tuple[type[FirmwareProfile], dict[str, Any]]] = {
    "marlin": (FirmwareProfile, {}),
    "marlin-advanced": (FirmwareProfile, {"name": "marlin-advanced", "advanced_ok": True}),
    "klipper": (KlipperProfile, {}),
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
    kind, defaults = _BUILTIN[key]
    kw = dict(defaults)
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
    return kind(**kw)
