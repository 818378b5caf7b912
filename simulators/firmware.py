"""The firmware of the virtual printer: Marlin host protocol, command queue, planner, heaters.

:class:`Firmware` is a deterministic state machine driven by time. Transports
hand it bytes with :meth:`Firmware.receive`, move its clock with
:meth:`Firmware.advance` (or :meth:`Firmware.run_sim` under the simulated
clock) and collect what it says with :meth:`Firmware.take_output`.

Model (Marlin 2.1, ``queue.cpp`` / ``planner.cpp``):

- bytes land in a receive ring of ``rx_buffer`` bytes; the line reader takes
  bytes from it only while the command queue (``command_buffer`` lines) has
  room, drops a ``;`` comment, and ignores characters past ``max_line − 1``;
- a line starting with ``N`` must carry the next line number and a correct
  ``*`` checksum (XOR of the bytes before ``*``); otherwise the firmware
  answers ``Error:<reason>, Last Line: <n>``, empties its receive ring,
  answers ``Resend: <n+1>`` and (per profile) ``ok``. ``M110 N<n>`` sets the
  line number. A line with ``*`` but no ``N`` is refused too;
- ``M112`` is acted on when the line is read (the emergency parser);
- commands run in order; a move waits for a free planner block and is
  acknowledged once queued, so the ``ok`` s are paced by the planner; blocks
  execute one after the other with trapezoidal timing;
- a command blocked for longer than ``busy_interval`` reports
  ``echo:busy: processing`` every interval; M109/M190 report temperatures
  every second instead (Marlin without BUSY_WHILE_HEATING);
- ``ok`` is followed by `` N<n> P<planner free> B<queue free>`` under
  ADVANCED_OK (N only when the line had a number).

Under the simulated clock, time moves only when the firmware is blocked
(planner full, dwell, heating...) or bytes are still on the wire (baud
pacing); it stands still while the firmware waits for the host, so a run is
reproducible byte for byte.

The class is assembled from one mixin per responsibility:
:mod:`simulators.line_protocol` (receive ring, line reader, line numbers,
checksums, resends), :mod:`simulators.planner` (running the command queue,
timing the planner's blocks) and :mod:`simulators.commands` (what each
command does, heaters, reports); this module keeps the state, its lifecycle
(power on, reset, kill), the byte I/O, the clock and the record.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Any

from printability.base.errors import PrinterError
from simulators.commands import CommandsMixin, Heater
from simulators.config import SimConfig
from simulators.deposition import Deposition, DepositionRecord, write_record
from simulators.faults import FaultInjector
from simulators.kinematics import Block, MotionState
from simulators.line_protocol import Disconnect, Entry, LineProtocolMixin, Stall, checksum
from simulators.planner import BUSY, PlannerMixin

__all__ = ["Disconnect", "Firmware", "Heater", "Stall", "Stats", "checksum"]

# Under the simulated clock a wait of years (G4 S1e9) would print a busy line every 2 s;
# after this many keepalives of one command the clock jumps straight to its end.
_SIM_KEEPALIVE_CAP = 1000


@dataclass
class Stats:
    """Counters of one run (all since the simulator started)."""

    bytes_in: int = 0
    bytes_out: int = 0
    bytes_dropped: int = 0
    lines_in: int = 0
    executed: int = 0
    resends: int = 0
    errors: dict[str, int] = field(default_factory=dict)
    unknown: int = 0
    busy_sent: int = 0
    cold_extrusions: int = 0
    refused_moves: int = 0
    resets: int = 0
    moves: int = 0
    blocks: int = 0
    motion_time: float = 0.0
    faults: list[tuple[str, int]] = field(default_factory=list)
    # log indices of commands whose planned moves a reset or kill dropped before they ran
    # (acknowledged, so a host resuming after the last acknowledged line does not resend them)
    lost: list[int] = field(default_factory=list)


class Firmware(LineProtocolMixin, PlannerMixin, CommandsMixin):
    """The simulated firmware (see the module docstring).

    Parameters
    ----------
    config
        The simulator configuration.
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.fw = config.firmware
        fw = self.fw
        self.motion = MotionState(config.machine, fw)
        self.deposition = Deposition(config.nozzle, quad_segs=config.quad_segs,
                                     chord_tolerance=config.chord_tolerance)
        self.faults = FaultInjector(config.faults)
        self.hotend = Heater(fw.ambient, fw.hotend_tau)
        self.bed = Heater(fw.ambient, fw.bed_tau)
        self.executed: list[tuple[int | None, str]] = []
        self.stats = Stats()
        self.now = 0.0
        self._out: list[bytearray | Stall | Disconnect] = []
        self._out_t: list[float] = []  # firmware time at which each _out item was said
        self._pending: deque[tuple[float, bytes]] = deque()
        self._pending_off = 0
        self._wire_free = 0.0
        self._power_on(banner=False)

    # ================================================================ lifecycle
    def _drop_planner(self) -> None:
        """Forget the planned blocks; the one running (already deposited) is not lost."""
        planner = getattr(self, "_planner", None)
        if planner:
            lost = sorted({b.index for b in list(planner)[1:]} - {planner[0].index})
            self.stats.lost.extend(i for i in lost if i >= 0)

    def _power_on(self, *, banner: bool) -> None:
        self._drop_planner()
        self.last_n = 0
        self._ring = bytearray()
        self._ep_line = bytearray()
        self._line = bytearray()
        self._line_overflow = False
        self._in_comment = False
        self._queue: deque[Entry] = deque()
        self._planner: deque[Block] = deque()
        self._exec_end = self.now          # end time of the block executing now
        self._prev_block: Block | None = None
        self._active: Generator[Any, None, None] | None = None
        self._wait: tuple[Any, ...] | None = None
        self._blocked_since: float | None = None
        self._keepalive_at = math.inf
        self._keepalive_kind = "busy"
        self._keepalives = 0
        # the busy keepalive interval (s), M113 S<s> changes it; inf: off
        self.busy_interval = self.fw.busy_interval
        self._autoreport = 0.0
        self._autoreport_at = math.inf
        self._storm = 0
        self._ordinal = 0
        self.halted = False
        self.motion.reset()
        self.hotend.set(0.0, self.now)
        self.bed.set(0.0, self.now)
        self.min_extrude_temp = 170.0
        if banner:
            for line in self.fw.banner:
                self._emit(line)

    def connect(self) -> None:
        """A host opened the port: the board resets (DTR) and greets it."""
        self.stats.resets += 1
        self._pending.clear()
        self._pending_off = 0
        self._power_on(banner=True)

    def _kill(self) -> None:
        self._emit(self.fw.kill_message)
        self.halted = True
        self._ring.clear()
        self._line.clear()
        self._queue.clear()
        self._drop_planner()
        self._planner.clear()
        self._active = None
        self._wait = None
        self.hotend.set(0.0, self.now)
        self.bed.set(0.0, self.now)

    # ================================================================ I/O
    def receive(self, data: bytes, now: float | None = None) -> None:
        """Bytes from the host; with baud pacing they arrive 10 bits per byte later."""
        if not data:
            return
        t = self.now if now is None else max(now, self.now)
        if self.config.baud:
            t = max(t, self._wire_free) + len(data) * 10.0 / self.config.baud
            self._wire_free = t
        self._pending.append((t, bytes(data)))
        self.stats.bytes_in += len(data)

    def pending_until(self) -> float:
        """Time the last byte received so far reaches the firmware (now if none waits), s."""
        return max(self._pending[-1][0], self.now) if self._pending else self.now

    def take_output(self) -> list[bytes | Stall | Disconnect]:
        """What the firmware said since the last call (bytes and link markers)."""
        return [item for _, item in self.take_output_timed()]

    def take_output_timed(self) -> list[tuple[float, bytes | Stall | Disconnect]]:
        """Like :meth:`take_output`, each item with the firmware time it was said at, s.

        A transport that runs the firmware ahead of the real clock (see
        :meth:`run_until`) holds each item back until that time.
        """
        out, self._out = self._out, []
        times, self._out_t = self._out_t, []
        return [(t, bytes(x) if isinstance(x, bytearray) else x)
                for t, x in zip(times, out, strict=True)]

    def _emit(self, line: str) -> None:
        data = (line + "\n").encode("latin-1", "replace")
        self.stats.bytes_out += len(data)
        if self._out and isinstance(self._out[-1], bytearray) and self._out_t[-1] == self.now:
            self._out[-1] += data  # in place: long runs stay linear
        else:
            self._out.append(bytearray(data))
            self._out_t.append(self.now)

    def _mark(self, item: Stall | Disconnect) -> None:
        self._out.append(item)
        self._out_t.append(self.now)

    # ================================================================ time
    def next_event(self) -> float:
        """The next time at which the firmware will do something without new input, s."""
        times = [self._keepalive_at if self._active is not None else math.inf,
                 self._autoreport_at]
        if self._pending:
            times.append(self._pending[0][0])
        if self._planner:
            times.append(self._exec_end)
        if self._wait is not None and self._wait[0] == "time":
            times.append(self._wait[1])
        return min(times)

    def _sim_event(self) -> float:
        """Next event that moves the simulated clock (never idle reports)."""
        times = []
        if self._pending and (self._pending[0][0] > self.now):
            times.append(self._pending[0][0])
        if self._active is not None and self._wait is not None:
            if self._wait[0] == "time":
                times.append(self._wait[1])
            elif self._planner:
                times.append(self._exec_end)
            if self._keepalives < _SIM_KEEPALIVE_CAP:
                times.append(self._keepalive_at)
        elif self._queue and self._planner:  # queued command waiting for the planner
            times.append(self._exec_end)
        return min(times) if times else math.inf

    @property
    def autoreport_interval(self) -> float:
        """The M155 temperature auto-report interval, s (0: off)."""
        return self._autoreport

    def idle_report(self) -> bool:
        """Simulated clock, host silent: the M155 temperature report a board sends while it
        waits. The simulated clock stands still while the firmware waits for the host, but a
        host's watchdog runs on the wall clock (OctoPrint, having turned auto-reports on,
        declares a silent printer dead); the transport calls this every auto-report interval
        of wall time the host stays silent. The report is said at the simulated now (the
        clock does not move). Returns whether one was said: auto-reports are on and nothing
        waits to run (a command blocked or queued moves the simulated clock itself)."""
        if self.halted or self._autoreport <= 0 or math.isfinite(self._sim_event()) \
                or self._pending or self._queue or self._active is not None:
            return False
        self._emit(self._temp_report())
        return True

    def run_sim(self, *, limit: float = math.inf) -> None:
        """Simulated clock: process everything that needs no new input from the host."""
        while True:
            self.advance(self.now)
            t = self._sim_event()
            if not math.isfinite(t) or t > limit or t <= self.now or self.halted:
                return  # idle until the host sends more (t <= now: nothing can move)
            self.now = max(self.now, t)

    def run_until(self, t: float) -> None:
        """Process every event up to time ``t`` (s) in order, each at its own time.

        Unlike :meth:`advance`, which does at ``now`` all that is due by then,
        this steps through the events between, so what the firmware says
        carries the time a real board would say it. A real-clock transport
        calls it with the arrival time of the bytes on the wire (ahead of the
        wall clock) and holds the answers until their time: the simulator's
        own computing then hides inside the wire time of the line, as a
        board's does inside its UART's.
        """
        self.advance(self.now)
        while not self.halted:
            ev = self.next_event()
            if not (self.now < ev <= t):
                break
            self.advance(ev)
        if t > self.now:
            self.advance(t)

    def advance(self, now: float) -> None:
        """Process everything due up to time ``now`` (s)."""
        self.now = max(self.now, now)
        if self.halted:
            self._pending.clear()
            self._pending_off = 0
            return
        while True:
            self._arrivals()
            progressed = self._read_lines()
            self._retire()
            progressed |= self._execute()
            if not progressed:
                break
        self._periodic()

    def drain(self) -> float:
        """Let the planner finish every queued block; returns the time it ends, s."""
        self.run_sim()
        while self._planner and not self.halted:
            self.now = max(self.now, self._exec_end)
            self.advance(self.now)
        return self.now

    def _periodic(self) -> None:
        if self._active is not None and self.now >= self._keepalive_at:
            self._keepalives += 1
            if self._keepalive_kind == "busy":
                self._emit(BUSY)
                self.stats.busy_sent += 1
                self._keepalive_at = self.now + self.busy_interval
            else:
                self._emit(self._temp_report(wait=True))
                self._keepalive_at = self.now + 1.0
        if self.now >= self._autoreport_at:
            self._emit(self._temp_report())
            self._autoreport_at = self.now + self._autoreport

    # ================================================================ status
    def status_line(self) -> str:
        """One line for a person watching: commands executed, position, layer, heaters.

        ``"1234 commands executed; at X10.00 Y20.00 Z0.60 C90.00; layer 3 (Z0.60) of 3
        deposited; hotend 210/210 °C, bed 60/60 °C; 2 resends"``: the position is the
        logical one (what M114 reports) of the last move planned, the layer counts the
        heights material was laid at so far, up to the nozzle's.
        """
        s, m = self.stats, self.motion
        pos = m.logical()
        letters = ("X", "Y", "Z", m.letter) if m.letter else ("X", "Y", "Z")
        at = " ".join(f"{k}{float(v):.2f}" for k, v in zip(letters, pos, strict=False))
        # The layer the nozzle is in, counted among the layers material was laid in so far.
        zs = sorted(self.deposition.layers)
        native_z = float(m.pos[2])
        below = [z for z in zs if z <= native_z + 1e-6]
        layer = (f"layer {len(below)} (Z{float(pos[2]):.2f}) of {len(zs)} deposited" if zs
                 else "nothing deposited yet")
        t = self.now
        heat = (f"hotend {self.hotend.temp(t):.0f}/{self.hotend.target:.0f} °C, "
                f"bed {self.bed.temp(t):.0f}/{self.bed.target:.0f} °C")
        extra = f"; {s.resends} resends" if s.resends else ""
        if self.halted:
            extra += "; HALTED (M112 or kill): needs a reset"
        return f"{s.executed} commands executed; at {at}; {layer}; {heat}{extra}"

    # ================================================================ record
    def record(self) -> DepositionRecord:
        """The deposition record so far (layers, executed log, statistics, MMC findings).

        Blocks still waiting in the planner are not printed yet; :meth:`drain` first for
        the record of a finished print."""
        s = self.stats
        stats = {
            "firmware": self.fw.name, "machine": self.config.machine.name,
            "nozzle": self.config.nozzle.spec, "clock": self.config.clock,
            "bytes_in": s.bytes_in, "bytes_out": s.bytes_out, "bytes_dropped": s.bytes_dropped,
            "lines_in": s.lines_in, "executed": s.executed, "resends": s.resends,
            "errors": dict(s.errors), "unknown_commands": s.unknown, "busy_sent": s.busy_sent,
            "cold_extrusions": s.cold_extrusions, "refused_moves": s.refused_moves,
            "resets": s.resets, "moves": s.moves,
            "lost_in_reset": [[i, *self.executed[i]] for i in s.lost],
            "planner_blocks": s.blocks,
            "motion_time_s": s.motion_time, "clock_s": self.now,
            "faults": [list(f) for f in s.faults],
            "extruded_mm": float(sum(lay.extruded for lay in self.deposition.layers.values())),
        }
        return self.deposition.record(self.executed, stats=stats, target=self.config.target)

    def write_record(self, path: str | None = None) -> DepositionRecord:
        """Write the record (to ``path`` or the configured one) atomically; returns it."""
        target = path or self.config.record
        if not target:
            raise PrinterError("no record path given: pass one or configure record=PATH")
        rec = self.record()
        write_record(rec, target)
        return rec
