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
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Any

from printability.errors import PrinterError
from simulators.config import SimConfig
from simulators.deposition import Deposition, DepositionRecord, write_record
from simulators.faults import FaultInjector
from simulators.kinematics import Block, MotionError, MotionState, junction_speed, trapezoid_time
from simulators.parsing import Command, parse_command

__all__ = ["Disconnect", "Firmware", "Heater", "Stall", "Stats", "checksum"]

ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "
ERR_NO_LINE_NO = "No Line Number with checksum, Last Line: "
BUSY = "echo:busy: processing"
KILLED = "Error:Printer halted. kill() called!"
COLD = "echo: cold extrusion prevented"

_EOL = re.compile(rb"[\r\n]")
# Under the simulated clock a wait of years (G4 S1e9) would print a busy line every 2 s;
# after this many keepalives of one command the clock jumps straight to its end.
_SIM_KEEPALIVE_CAP = 1000
_N_PREFIX = re.compile(r"N\s*(-?\d+)\s*")
_STRTOL = re.compile(r"\s*[+-]?\d+")
# Marlin's EMERGENCY_PARSER: "M112" alone on a line (after an optional line number) kills at
# once, even while the command queue is full.
_EMERGENCY = re.compile(rb"\s*(?:N\s*-?\d+\s*)?M112\s*(?:[*;].*)?$")

# Commands the firmware accepts and (for the simulation) need no effect.
_NOOP = frozenset({
    "M17", "M18", "M84", "M106", "M107", "M73", "M75", "M76", "M77", "M117", "M118", "M201",
    "M205", "M221", "M500", "M501", "M502", "M503", "M900", "M907", "M92", "M80", "M81",
    "M111", "M119", "M31", "M42", "M420", "M149", "M851", "M593", "M486", "M999", "G21",
    "G29", "G10", "G11", "M0", "M1", "M16", "M23", "M24", "M25", "M27", "M28", "M29", "M30",
    "M32", "M33", "M928", "M413", "M163", "M164", "M141", "M191", "M150", "M600",
})
_KLIPPER_MACROS = re.compile(r"^[A-Z][A-Z0-9]*_[A-Z0-9_]+\b|^(?:PAUSE|RESUME|CANCEL_PRINT|"
                             r"STATUS|RESTART|FIRMWARE_RESTART|SAVE_CONFIG)\b", re.IGNORECASE)


def checksum(data: bytes | str) -> int:
    """Marlin's line checksum: XOR of all bytes (before ``*``)."""
    if isinstance(data, str):
        data = data.encode("latin-1", "replace")
    c = 0
    for b in data:
        c ^= b
    return c


@dataclass(frozen=True)
class Stall:
    """Output marker: the link says nothing for ``seconds`` of real time."""

    seconds: float


@dataclass(frozen=True)
class Disconnect:
    """Output marker: the link drops (the board reset); transports reconnect."""


class Heater:
    """First-order heater: T → setpoint (or ambient when off) with time constant ``tau``."""

    def __init__(self, ambient: float, tau: float) -> None:
        self.ambient, self.tau = ambient, tau
        self.t0, self.T0, self.target = 0.0, ambient, 0.0

    def _eq(self) -> float:
        return self.target if self.target > 0 else self.ambient

    def temp(self, t: float) -> float:
        eq = self._eq()
        return eq + (self.T0 - eq) * math.exp(-max(t - self.t0, 0.0) / self.tau)

    def set(self, target: float, t: float) -> None:
        self.T0, self.t0, self.target = self.temp(t), t, max(target, 0.0)

    def reach_time(self, t: float, window: float) -> float:
        """When the temperature comes within ``window`` °C of the setpoint, s."""
        eq, T = self._eq(), self.temp(t)
        gap = abs(T - eq)
        return t if gap <= window else t + self.tau * math.log(gap / window)

    def power(self, t: float) -> int:
        return 127 if self.target > 0 and self.temp(t) < self.target - 0.5 else 0


@dataclass
class _Entry:
    n: int | None
    cmd: Command
    drop_ok: bool = False
    duplicate_ok: bool = False
    busy: int = 0
    corrupt_reply: bool = False


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


class Firmware:
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
        self._queue: deque[_Entry] = deque()
        self._planner: deque[Block] = deque()
        self._exec_end = self.now          # end time of the block executing now
        self._prev_block: Block | None = None
        self._active: Generator[Any, None, None] | None = None
        self._wait: tuple[Any, ...] | None = None
        self._blocked_since: float | None = None
        self._keepalive_at = math.inf
        self._keepalive_kind = "busy"
        self._keepalives = 0
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

    def _arrivals(self) -> None:
        room = self.fw.rx_buffer - len(self._ring)
        while self._pending and self._pending[0][0] <= self.now and not self.halted:
            data = self._pending[0][1]
            off = self._pending_off  # consumed bytes of the head chunk (no O(n²) slicing)
            left = len(data) - off
            if left <= room:
                self._take(data[off:])
                room -= left
                self._pending.popleft()
                self._pending_off = 0
            elif self.fw.rx_overflow_drops:
                self._take(data[off:off + room])
                self.stats.bytes_dropped += left - room
                room = 0
                self._pending.popleft()
                self._pending_off = 0
            else:  # flow control holds the rest back
                if room > 0:
                    self._take(data[off:off + room])
                    self._pending_off = off + room
                break
            if self.halted:
                return

    def _take(self, data: bytes) -> None:
        """Bytes enter the receive ring; Marlin's emergency parser sees them on the way."""
        self._ring += data
        if self.fw.name == "klipper":
            return
        start = 0
        while True:
            m = _EOL.search(data, start)
            piece = data[start:m.start() if m else len(data)]
            if len(self._ep_line) < 64:
                self._ep_line += piece[:64]
            if not m:
                return
            if _EMERGENCY.match(self._ep_line):
                self.executed.append((None, "M112"))
                self._kill()
                return
            self._ep_line.clear()
            start = m.end()

    def _periodic(self) -> None:
        if self._active is not None and self.now >= self._keepalive_at:
            self._keepalives += 1
            if self._keepalive_kind == "busy":
                self._emit(BUSY)
                self.stats.busy_sent += 1
                self._keepalive_at = self.now + self.fw.busy_interval
            else:
                self._emit(self._temp_report(wait=True))
                self._keepalive_at = self.now + 1.0
        if self.now >= self._autoreport_at:
            self._emit(self._temp_report())
            self._autoreport_at = self.now + self._autoreport

    # ================================================================ reading
    def _read_lines(self) -> bool:
        progressed = False
        while len(self._queue) < self.fw.command_buffer and self._ring and not self.halted:
            m = _EOL.search(self._ring)
            end = m.start() if m else len(self._ring)
            chunk = self._ring[:end]
            del self._ring[:end + (1 if m else 0)]
            progressed = True
            if not self._in_comment:
                semi = chunk.find(b";")
                if semi >= 0:
                    chunk = chunk[:semi]
                    self._in_comment = True
                room = self.fw.max_line - 1 - len(self._line)
                if len(chunk) > room:
                    chunk = chunk[:max(room, 0)]
                self._line += chunk
            if m:
                line = bytes(self._line)
                self._line.clear()
                self._in_comment = False
                progressed = True
                if line.strip():
                    self._process_line(line)
            else:
                break
        return progressed

    def _line_error(self, err: str) -> None:
        self.stats.errors[err.split(",")[0]] = self.stats.errors.get(err.split(",")[0], 0) + 1
        self._emit(f"Error:{err}{self.last_n}")
        # Marlin empties the receive ring before asking for the resend.
        self._ring.clear()
        self._line.clear()
        self._in_comment = False
        while self._pending and self._pending[0][0] <= self.now:
            self._pending.popleft()
            self._pending_off = 0
        self._emit(f"Resend: {self.last_n + 1}")
        self.stats.resends += 1
        if self.fw.ok_after_resend:
            self._emit("ok")

    def _process_line(self, raw: bytes) -> None:
        text = raw.decode("latin-1").strip()
        if not text:
            return
        self.stats.lines_in += 1
        self._ordinal += 1
        n_match = _N_PREFIX.match(text)
        entry_flags: dict[str, Any] = {}
        if self.config.faults.faults:
            key = int(n_match.group(1)) if n_match else self._ordinal
            for f in self.faults.draw(key):
                self.stats.faults.append((f.kind, key))
                if f.kind == "drop-line":
                    return
                if f.kind == "corrupt":
                    text = self.faults.corrupt(text.encode("latin-1")).decode("latin-1")
                    n_match = _N_PREFIX.match(text)
                elif f.kind == "resend-storm":
                    self._storm = max(self._storm, int(f.arg))
                elif f.kind == "stall":
                    self._mark(Stall(f.arg))
                elif f.kind == "disconnect":
                    self._mark(Disconnect())
                    self.stats.resets += 1
                    self._power_on(banner=False)
                    return
                elif f.kind == "drop-ok":
                    entry_flags["drop_ok"] = True
                elif f.kind == "duplicate-ok":
                    entry_flags["duplicate_ok"] = True
                elif f.kind == "busy":
                    entry_flags["busy"] = max(1, int(f.arg))
                elif f.kind == "corrupt-reply":
                    entry_flags["corrupt_reply"] = True
        n: int | None = None
        star = text.rfind("*")
        if self.fw.checksums:
            if n_match:
                npos = n_match
                if "M110" in text:
                    m2 = re.search(r"N\s*(-?\d+)", text[n_match.end():])
                    if m2 and text.find("M110") < n_match.end() + m2.start():
                        npos = m2
                n = int(npos.group(1))
                if n != self.last_n + 1 and "M110" not in text:
                    return self._line_error(ERR_LINE_NO)
                if star < 0:
                    return self._line_error(ERR_NO_CHECKSUM)
                # strtol(): leading digits count, anything after them is ignored, none is 0.
                m_sum = _STRTOL.match(text, star + 1)
                given = int(m_sum.group()) if m_sum else 0
                if given != checksum(text[:star]) or self._storm > 0:
                    self._storm = max(self._storm - 1, 0)
                    return self._line_error(ERR_CHECKSUM)
                self.last_n = n
                body = text[n_match.end():star]
            elif star >= 0:
                return self._line_error(ERR_NO_LINE_NO)
            else:
                body = text
        else:  # Klipper: line numbers and checksums are stripped, never checked
            if n_match:
                n = int(n_match.group(1))
            body = text[n_match.end() if n_match else 0:star if star >= 0 else len(text)]
        cmd = parse_command(body)
        if cmd.code == "M112":
            self.executed.append((n, cmd.text))
            self._kill()
            return
        self._queue.append(_Entry(n, cmd, **entry_flags))

    def _kill(self) -> None:
        self._emit(KILLED if self.fw.name != "klipper" else "!! Shutdown due to M112 command")
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

    # ================================================================ planner
    def _retire(self) -> None:
        while self._planner and self._exec_end <= self.now:
            self._planner.popleft()
            if self._planner:
                self._start_block(self._exec_end)

    def _start_block(self, t: float) -> None:
        b = self._planner[0]
        if b.e1 > b.e0 + 1e-12:  # material leaves the orifice, moving or not
            # Deposited when the block runs: a kill (M112) empties the planner unprinted.
            self.deposition.add(b.start, b.end, b.e1 - b.e0, b.index)
        prev = self._prev_block
        self._entry = prev.exit_speed if prev is not None and t == self._exec_end else 0.0
        self._exec_start = t
        self._time_block(b)
        self._prev_block = b

    def _time_block(self, b: Block) -> None:
        """Duration of the executing block from its entry speed and the next block (if any)."""
        nxt = self._planner[1] if len(self._planner) > 1 else None
        b.exit_speed = junction_speed(b, nxt, self.fw.junction_deviation) if nxt else 0.0
        self.stats.motion_time -= b.duration
        if b.fixed_time is not None:
            b.duration = b.fixed_time
        else:
            b.duration = trapezoid_time(b.length, self._entry, b.exit_speed, b.speed, b.accel)
        self.stats.motion_time += b.duration
        self._exec_end = self._exec_start + b.duration

    def _push_block(self, b: Block) -> None:
        idle = not self._planner
        self._planner.append(b)
        self.stats.blocks += 1
        if idle:
            self._prev_block = None
            self._start_block(self.now)
        elif len(self._planner) == 2:
            # The executing block was planned to stop; with a successor it may keep its
            # speed through the junction (the planner re-plans its tail).
            self._time_block(self._planner[0])

    # ================================================================ execution
    def _execute(self) -> bool:
        progressed = False
        while not self.halted:
            if self._active is None:
                if not self._queue:
                    return progressed
                entry = self._queue[0]
                self.executed.append((entry.n, entry.cmd.text))
                self.stats.executed += 1
                gen = self._run(entry)
                self._active = gen
                self._wait = None
                self._blocked_since = None
            if self._wait is not None and not self._satisfied(self._wait):
                if self._blocked_since is None:
                    self._blocked_since = self.now
                    temp_wait = self._wait[0] == "time" and len(self._wait) > 2
                    self._keepalive_kind = "temp" if temp_wait else "busy"
                    self._keepalive_at = self.now + (1.0 if temp_wait else self.fw.busy_interval)
                return progressed
            try:
                self._wait = self._active.send(None)
                progressed = True
                continue
            except StopIteration:
                pass
            self._active = None
            self._wait = None
            self._keepalive_at = math.inf
            self._keepalives = 0
            self._ok(self._queue[0])  # B counts the finished command, as in Marlin
            self._queue.popleft()
            progressed = True
        return progressed

    def _satisfied(self, wait: tuple[Any, ...]) -> bool:
        kind = wait[0]
        if kind == "slot":
            return len(self._planner) < self.fw.planner_buffer
        if kind == "sync":
            return not self._planner
        return self.now >= wait[1]

    def _ok(self, entry: _Entry) -> None:
        for _ in range(entry.busy):
            self._emit(BUSY)
            self.stats.busy_sent += 1
        if entry.drop_ok or entry.cmd.code == "M105":
            return
        text = "ok"
        if self.fw.advanced_ok:
            if entry.n is not None:
                text += f" N{entry.n}"
            free_b = self.fw.command_buffer - len(self._queue)
            text += f" P{self.fw.planner_buffer - len(self._planner)} B{free_b}"
        if entry.corrupt_reply:
            text = self.faults.corrupt(text.encode()).decode("latin-1")
        self._emit(text)
        if entry.duplicate_ok:
            self._emit(text)

    # ---------------------------------------------------------------- commands
    def _run(self, entry: _Entry) -> Generator[Any, None, None]:
        cmd = entry.cmd
        code = cmd.code
        m = self.motion
        if code in ("G0", "G1", "G2", "G3"):
            try:
                if code in ("G0", "G1"):
                    blocks = m.linear(cmd)
                else:
                    blocks = m.arc(cmd, clockwise=code == "G2")
            except MotionError as exc:
                self.stats.refused_moves += 1
                self._emit(str(exc))
                return
            self.stats.moves += 1
            cold = False
            for b in blocks:
                if b.e1 > b.e0 and self.hotend.temp(self.now) < self.min_extrude_temp:
                    cold = True
                    b.e1 = b.e0
                yield ("slot",)
                b.index = len(self.executed) - 1
                self._push_block(b)
            if cold:
                self.stats.cold_extrusions += 1
                self._emit(COLD)
            return
        if code == "G4":
            ms = cmd.value("P", 0.0) or 0.0
            s = cmd.value("S")
            yield ("sync",)
            yield ("time", self.now + (s if s is not None else ms / 1000.0))
            return
        if code == "G28":
            yield ("sync",)
            m.home(cmd)
            yield ("time", self.now + self.fw.homing_time)
            return
        if code in ("G90", "G91"):
            m.relative = code == "G91"
            return
        if code in ("M82", "M83"):
            m.e_relative = code == "M83"
            return
        if code == "G92":
            m.set_position(cmd)
            return
        if code in ("G93", "G94"):
            if code == "G93" and m.machine.feed_policy != "inverse-time":
                self._unknown(cmd)
            else:
                m.inverse_time = code == "G93"
            return
        if code == "M400":
            yield ("sync",)
            return
        if code in ("M104", "M109"):
            target = cmd.value("S", cmd.value("R"))
            if target is not None:
                self.hotend.set(target, self.now)
            if code == "M109" and target is not None and target > 0:
                heating_only = cmd.has_value("S")
                if not (heating_only and self.hotend.temp(self.now) >= target):
                    t = self.hotend.reach_time(self.now, self.fw.temp_window)
                    yield ("time", t + self.fw.hotend_residency, "temp")
            return
        if code in ("M140", "M190"):
            target = cmd.value("S", cmd.value("R"))
            if target is not None:
                self.bed.set(target, self.now)
            if code == "M190" and target is not None and target > 0:
                heating_only = cmd.has_value("S")
                if not (heating_only and self.bed.temp(self.now) >= target):
                    t = self.bed.reach_time(self.now, self.fw.temp_window)
                    yield ("time", t + self.fw.bed_residency, "temp")
            return
        if code == "M105":
            self._emit("ok" + self._temp_report())
            return
        if code == "M155":
            s = cmd.value("S", 0.0) or 0.0
            self._autoreport = max(s, 0.0)
            self._autoreport_at = self.now + s if s > 0 else math.inf
            return
        if code == "M110":
            # The number was taken when the line was read; a bare M110 N sets it here.
            if entry.n is None and cmd.has_value("N"):
                self.last_n = int(cmd.words["N"])  # type: ignore[arg-type]
            return
        if code == "M114":
            self._emit(self._position_report())
            return
        if code == "M115":
            for line in self._capabilities():
                self._emit(line)
            return
        if code == "M204":
            for key in ("S", "P"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.acceleration = float(cmd.words[key])  # type: ignore[arg-type]
            return
        if code == "M203":
            for key in ("X", "Y"):
                if cmd.has_value(key) and cmd.words[key] > 0:  # type: ignore[operator]
                    m.max_feed_xy = float(cmd.words[key])  # type: ignore[arg-type]
            return
        if code == "M220":
            if cmd.has_value("S") and cmd.words["S"] > 0:  # type: ignore[operator]
                m.feed_percent = float(cmd.words["S"])  # type: ignore[arg-type]
            return
        if code == "M302":
            if cmd.has_value("P"):
                self.min_extrude_temp = 0.0 if cmd.words["P"] else 170.0
            elif cmd.has_value("S"):
                self.min_extrude_temp = float(cmd.words["S"])  # type: ignore[arg-type]
            return
        if code.startswith("T"):
            if code != "T0":
                self._emit(f"echo:{code} Invalid extruder")
            return
        if code in _NOOP:
            return
        self._unknown(cmd)

    def _unknown(self, cmd: Command) -> None:
        self.stats.unknown += 1
        if self.fw.name == "klipper":
            if _KLIPPER_MACROS.match(cmd.text):
                return  # an extended command (macro): accepted
            self._emit(self.fw.unknown_format.format(cmd.text.split(" ")[0].upper()))
            return
        self._emit(self.fw.unknown_format.format(cmd.text))

    # ---------------------------------------------------------------- reports
    def _temp_report(self, *, wait: bool = False) -> str:
        t = self.now
        h, b = self.hotend, self.bed
        if self.fw.name == "klipper":
            return f" B:{b.temp(t):.1f} /{b.target:.1f} T0:{h.temp(t):.1f} /{h.target:.1f}"
        text = (f" T:{h.temp(t):.2f} /{h.target:.2f} B:{b.temp(t):.2f} /{b.target:.2f} "
                f"@:{h.power(t)} B@:{b.power(t)}")
        if wait:
            text += " W:?"
        return text

    def _position_report(self) -> str:
        m = self.motion
        lg = m.logical()
        spu = self.fw.steps_per_unit
        names = ["X", "Y", "Z"] + ([m.letter] if m.letter else [])
        pos = " ".join(f"{L}:{lg[i]:.2f}" for i, L in enumerate(names))
        idx = [0, 1, 2, 3][:len(names)]
        counts = " ".join(f"{names[k]}:{round(m.pos[i] * spu[i])}" for k, i in enumerate(idx))
        return f"{pos} E:{m.e:.2f} Count {counts}"

    def _capabilities(self) -> list[str]:
        m = self.motion
        if self.fw.name == "klipper":
            return [f"FIRMWARE_NAME:Klipper FIRMWARE_VERSION:{self.fw.firmware_name}"]
        axes = 4 if m.letter else 3
        mc = self.config.machine
        lines = [f"FIRMWARE_NAME:{self.fw.firmware_name} SOURCE_CODE_URL:github.com/"
                 f"MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:{mc.name} "
                 f"KINEMATICS:Cartesian EXTRUDER_COUNT:1 AXIS_COUNT:{axes}"]
        caps = [("SERIAL_XON_XOFF", 0), ("BINARY_FILE_TRANSFER", 0), ("EEPROM", 0),
                ("VOLUMETRIC", 1), ("AUTOREPORT_POS", 0), ("AUTOREPORT_TEMP", 1),
                ("PROGRESS", 0), ("PRINT_JOB", 1), ("AUTOLEVEL", 0), ("RUNOUT", 0),
                ("Z_PROBE", 0), ("LEVELING_DATA", 0), ("BUILD_PERCENT", 0),
                ("SOFTWARE_POWER", 0), ("TOGGLE_LIGHTS", 0), ("CASE_LIGHT_BRIGHTNESS", 0),
                ("EMERGENCY_PARSER", 1), ("HOST_ACTION_COMMANDS", 0), ("PROMPT_SUPPORT", 0),
                ("SDCARD", 0), ("REPEAT", 0), ("SD_WRITE", 0), ("AUTOREPORT_SD_STATUS", 0),
                ("LONG_FILENAME", 0), ("EXTENDED_M20", 0), ("THERMAL_PROTECTION", 1),
                ("MOTION_MODES", 0), ("ARCS", 1), ("BABYSTEPPING", 0),
                ("CHAMBER_TEMPERATURE", 0), ("COOLER_TEMPERATURE", 0), ("MEATPACK", 0),
                ("CONFIG_EXPORT", 0), ("ADVANCED_OK", int(self.fw.advanced_ok))]
        lines += [f"Cap:{k}:{v}" for k, v in caps]
        if m.letter:
            lo = "none" if mc.full_turn else f"{mc.angle_min:g}"
            hi = "none" if mc.full_turn else f"{mc.angle_max:g}"
            lines.append(f"Cap:ROTARY_AXIS:{m.letter}")
            lines.append(f"echo:Rotary axis {m.letter} (deg) min:{lo} max:{hi} "
                         f"feed_policy:{mc.feed_policy}")
        return lines

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
