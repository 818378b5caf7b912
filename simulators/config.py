"""Configuration of the virtual printer: the simulator setup and its firmware profile.

:class:`SimConfig` holds everything a simulator instance needs; :func:`make_config`
builds one from the string options the CLI and URLs use. The firmware profiles
(:class:`FirmwareProfile`, :func:`firmware_profile`) are defined in
:mod:`simulators.profiles` and re-exported here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from printability.base.errors import InputError
from printability.base.options import SIM_CLOCKS
from printability.model.layers import LayerStack
from printability.model.machine import Machine, builtin_profiles, load_machine_file, parse_machine
from printability.model.nozzle import Nozzle, parse_nozzle
from simulators.faults import FaultPlan
from simulators.profiles import FirmwareProfile, KlipperProfile, firmware_profile

__all__ = ["FirmwareProfile", "KlipperProfile", "SimConfig", "firmware_profile", "make_config",
           "resolve_machine"]


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
        SPECs (see :func:`printability.model.machine.parse_machine`, :func:`parse_nozzle`).
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
