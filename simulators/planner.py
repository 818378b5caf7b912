"""Running the command queue and the planner: one command at a time, blocks in order.

The command at the head of the queue runs as a generator that waits for a
free planner block, an empty planner or a time; it is acknowledged (``ok``,
with ADVANCED_OK's counters) when it finishes. Planned blocks execute one
after the other with trapezoidal timing and junction speeds. Mixed into
:class:`simulators.firmware.Firmware`, whose docstring describes the model.
"""

from __future__ import annotations

import math
from typing import Any

from simulators.kinematics import Block, junction_speed, trapezoid_time
from simulators.line_protocol import Entry

__all__ = ["BUSY", "PlannerMixin"]

BUSY = "echo:busy: processing"


class PlannerMixin:
    """Queue execution and planner of :class:`simulators.firmware.Firmware`."""

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
                    self._keepalive_at = self.now + (1.0 if temp_wait else self.busy_interval)
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

    def _ok(self, entry: Entry) -> None:
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

