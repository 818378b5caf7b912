"""The virtual T-T-R printer (docs/design.md §1, §5).

A software printer that real hosts talk to as if it were hardware — Marlin's
host protocol with line numbers, checksums, resends, busy and temperature
reports, paced by a receive ring, a command queue and a planner — and that
records what it deposits: every extruding move sweeps the nozzle footprint
(turned by the rotary axis) into the current layer.

Transports: a pseudo-terminal and TCP on loopback (:mod:`simulators.transports`),
and the in-process pyserial URL ``printsim://`` (importing this package
registers it). ``printability simulate`` starts one from the command line.

This package speaks bytes and G-code lines; it uses the core's nozzles,
machines and layers for the deposition record, and the core never imports it.
"""

from __future__ import annotations

import serial

from simulators.config import FirmwareProfile, SimConfig, firmware_profile, make_config
from simulators.deposition import DepositionRecord, Violation, write_record
from simulators.faults import Fault, FaultPlan
from simulators.firmware import Firmware, checksum
from simulators.transports import Link, PtyServer, TcpServer

__all__ = [
    "DepositionRecord",
    "Fault",
    "FaultPlan",
    "Firmware",
    "FirmwareProfile",
    "Link",
    "PtyServer",
    "SimConfig",
    "TcpServer",
    "Violation",
    "checksum",
    "firmware_profile",
    "make_config",
    "write_record",
]

if "simulators.urlhandler" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("simulators.urlhandler")
