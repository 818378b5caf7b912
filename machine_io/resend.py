"""Lines in flight: the numbered history, the send window, and what each reply does.

Every line sent is kept by number; replies (``ok``, ``Resend``, ``Error``,
``busy``, a restart banner, host actions) and silences move the
acknowledged and next-to-send counters, telling stale resend requests from
genuine ones and retransmitting when in doubt. :meth:`ResendMixin._pump_once`
is one step of that machine. Mixed into :class:`machine_io.host.Host`, whose
docstring states the rules this bookkeeping keeps.
"""

from __future__ import annotations

import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from machine_io.protocol import (
    LONG_COMMANDS,
    Reply,
    command_code,
    frame,
    is_protocol_error,
    parse_reply,
)
from printability.base.errors import excerpt

__all__ = ["ResendMixin"]


@dataclass
class _Sent:
    """One transmission awaiting its reply."""

    number: int
    size: int
    seq: int
    long: bool
    heating: bool = False  # a heating wait (M109, M190, M191)


# Marlin's DEFAULT_KEEPALIVE_INTERVAL, s: how often a firmware with HOST_KEEPALIVE_FEATURE
# says "busy:" while a command blocks, until an M113 S<n> changes it.
_MARLIN_KEEPALIVE_INTERVAL = 2.0
# Replies already waiting that _take_waiting handles before transmitting: a board that never
# stops talking must not keep the host from sending (or from noticing a cancel).
_MAX_WAITING = 256
_M113_S = re.compile(r"\bS\s*(\d+(?:\.\d*)?)", re.IGNORECASE)
_HEATING_WAITS = frozenset({"M109", "M190", "M191"})
# Replies a firmware sends because of the lines it was sent: they restart the silence clock.
_ALIVE = frozenset({"ok", "resend", "busy", "error", "start", "action"})


class StopStreaming(Exception):
    """Internal: unwind the streaming loop (the reason is in ``Host._stop_reason``)."""


# Lines kept below the last acknowledged one: a Resend asks for a line after the last the
# firmware accepted (at or after the acknowledged ones), so older lines are never needed again.
_KEEP_BEHIND = 4096


class _History:
    """A list indexed by line number that forgets lines long acknowledged.

    The host keeps every line it numbered (frame, text, owner) for retransmission; kept for
    a whole print, a 200 MB file's millions of lines would take gigabytes by the end of it.
    Supports ``len`` (the next line number), indexing, ``append`` and ``del h[k:]``.
    """

    __slots__ = ("_base", "_items")

    def __init__(self, first: object) -> None:
        self._base = 0  # line number of _items[0]
        self._items = [first]

    def __len__(self) -> int:
        return self._base + len(self._items)

    def __getitem__(self, number: int) -> Any:
        if number < self._base:
            raise IndexError(f"line {number} was forgotten (kept from {self._base})")
        return self._items[number - self._base]

    def append(self, item: object) -> None:
        self._items.append(item)

    def __delitem__(self, cut: slice) -> None:
        if cut.stop is not None or cut.step is not None or (cut.start or 0) < self._base:
            raise IndexError("only a tail of kept lines can be deleted")
        del self._items[cut.start - self._base:]

    def forget_before(self, number: int) -> None:
        """Drop the lines numbered below ``number``."""
        if number > self._base:
            del self._items[:number - self._base]
            self._base = number


class ResendMixin:
    """The line bookkeeping and reply handling of :class:`machine_io.host.Host`."""

    def _reset_counters(self) -> None:
        # index = line number; 0 is the handshake
        self._frames: _History = _History(b"")
        self._texts: _History = _History("")
        self._owner: _History = _History(-1)
        self._next = 1
        self._max_sent = 0
        self._acked = 0
        self._acked_reliable = 0
        self._outstanding: deque[_Sent] = deque()
        self._out_bytes = 0
        self._seq = 0
        self._rewind_target = 0
        self._rewind_seq = 0
        self._resend_oks = 0
        self._resend_ok_deadline = 0.0
        self._last_genuine = 0
        self._genuine_count = 0
        self._report_buffer: int | None = None
        self._last_rx = time.monotonic()
        self._timeouts_in_row = 0
        self._lines_sent = 0
        self._resends = 0
        self._stale = 0
        self._timeouts = 0
        self._reconnects = 0
        self._bytes_sent = 0
        self._barrier_number = 0
        self._barrier_ok = False
        self._stop_reason: str | None = None
        self._injected: list[tuple[int, tuple[str, ...]]] = []
        self._in_doubt: list[tuple[int, int]] = []
        self._restarted = self._fatal = self._failed = False
        self._suspicious = 0
        self._error_kind: str | None = None
        self._deferred: tuple[int, float] | None = None
        self._quiet_until: float | None = None
        self._received = 0  # last line the firmware said it has (Error + Resend agreeing)
        self._error_last_line: int | None = None
        self._timeout_seq = -(10**9)
        self._cancel_done = False
        # Host keepalive (Marlin's "busy:" lines while a command blocks): once seen, a long
        # command's silence means a lost line or ok, not a slow command (see _current_timeout).
        self._keepalive_seen = False
        self._keepalive_off = False  # the file sent M113 S0
        self._keepalive_interval = _MARLIN_KEEPALIVE_INTERVAL
        self._last_busy: float | None = None
        self._keepalive_gap = 0.0
        self._reconnects_in_row = 0
        self._acked_at_reconnect = -1
        self._reconnect_failure: str | None = None
        # Temperature lines: a heating wait's reports (Marlin marks them " W:") show the
        # firmware at work; auto-reports (M155) come whatever happened to the lines in flight.
        self._autoreport_seen = False
        self._wait_reports_marked = False
        self._probed = 0  # line a silent long command was last retransmitted from (probe)

    def _send_ahead(self) -> bool:
        mode = self.config.mode
        if mode == "ping-pong":
            return False
        return self.firmware.advanced_ok

    def _can_transmit(self, size: int) -> bool:
        if self._resend_oks:
            return False  # wait for the ok that goes with a Resend
        n_out = len(self._outstanding)
        if n_out == 0:
            return True
        if not self._send_ahead() or self._report_buffer is None:
            return False
        return (n_out < min(self._report_buffer, self.config.max_window)
                and self._out_bytes + size <= self.config.rx_buffer)

    def _append(self, text: str, owner: int) -> None:
        # forget in batches (a list's head is cheap to cut once, not once per line)
        if self._acked - self._frames._base > 2 * _KEEP_BEHIND:
            for history in (self._frames, self._texts, self._owner):
                history.forget_before(self._acked - _KEEP_BEHIND)
        n = len(self._frames)
        self._frames.append(frame(n, text))
        self._texts.append(text)
        self._owner.append(owner)

    def _transmit(self, number: int) -> None:
        data = self._frames[number]
        self._seq += 1
        code = command_code(self._texts[number])
        if code == "M113":
            self._on_m113(self._texts[number])
        self._outstanding.append(_Sent(number, len(data), self._seq, code in LONG_COMMANDS,
                                       code in _HEATING_WAITS))
        self._out_bytes += len(data)
        self.transcript.write("Send", data[:-1].decode("utf-8", errors="replace"))
        self._write(data)
        self._lines_sent += 1
        if number > self._max_sent:
            self._max_sent = number
        self._next = number + 1

    def _pop_front(self) -> _Sent | None:
        if not self._outstanding:
            return None
        s = self._outstanding.popleft()
        self._out_bytes -= s.size
        return s

    def _set_acked(self, number: int, *, reliable: bool) -> None:
        if number > self._acked:
            self._acked = number
            if number >= self._last_genuine:
                self._genuine_count = 0
        if reliable and number > self._acked_reliable:
            self._acked_reliable = number
        self._timeouts_in_row = 0

    def _alive(self, reply: Reply) -> bool:
        """Whether ``reply`` shows the firmware at work on the lines in flight, which
        restarts the silence clock.

        Unsolicited lines do not: a firmware that auto-reports its temperatures
        (M155) or positions says something every second or two whatever became
        of the line in flight, and counting those lines kept the host waiting
        for ever for an ``ok`` that was lost. A temperature report counts during
        a heating wait (the wait's own reports), when it is marked as one
        (Marlin's `` W:``) or no auto-report has been seen.
        """
        kind = reply.kind
        if kind in _ALIVE:
            return True
        if kind != "temperature":
            return False
        if " W:" in reply.text:
            self._wait_reports_marked = True
            return True
        if not any(s.heating for s in self._outstanding):
            self._autoreport_seen = True
            return False
        return not self._autoreport_seen

    def _handle(self, reply: Reply, now: float) -> None:
        kind = reply.kind
        if self._alive(reply):
            self._last_rx = now
        if kind == "ok":
            self._on_ok(reply)
        elif kind == "resend":
            self._on_resend(reply.number or 0, now)
        elif kind == "busy":
            self._on_busy(now)  # alive: the clock was restarted above
        elif kind == "error":
            self._on_error(reply.text)
        elif kind == "start":
            self._on_restart()
        elif kind == "action":
            self._on_action(reply.text)
        elif kind == "temperature":
            self._observe(reply)
        elif kind == "echo" and "unknown command" in reply.text.lower():
            self._note(f"firmware: {reply.text}")

    def _on_ok(self, reply: Reply) -> None:
        if reply.buffer is not None:
            self._report_buffer = reply.buffer
        text = reply.text
        if "T:" in text:
            self._observe(reply)
            # Only M105 answers "ok T:…": the numbered barrier, accepted after every line.
            if self._barrier_number and self._max_sent >= self._barrier_number:
                self._barrier_ok = True
        if self._resend_oks and (reply.number is None or reply.number <= self._acked_reliable):
            self._resend_oks -= 1  # the ok that follows a Resend
            return
        n = reply.number
        if n is not None:
            # ADVANCED_OK names the line: duplicates and stale oks are recognised, and a
            # number never sent is a garbled reply.
            if n <= self._acked_reliable or n > self._max_sent:
                return
            if any(s.number <= n for s in self._outstanding):
                # Lines refused after an earlier error may sit behind newer transmissions.
                keep = deque(s for s in self._outstanding if s.number > n)
                self._out_bytes = sum(s.size for s in keep)
                self._outstanding = keep
            self._set_acked(n, reliable=True)
            return
        s = self._pop_front()
        if s is None:
            return  # an ok nobody waits for (a duplicate): nothing to free
        if not self.firmware.advanced_ok:
            self._set_acked(s.number, reliable=False)

    def _on_resend(self, number: int, now: float) -> None:
        self._resend_oks += 1
        self._resend_ok_deadline = now + self.config.resend_ok_timeout
        if number < 1 or number > self._max_sent + 1:
            self._note(f"ignored a resend request for line {number} (never sent)")
            return
        if number <= self._acked_reliable or number < self._frames._base:
            # The firmware acknowledged that line (long ago, if it was forgotten): either the
            # request is garbled or the firmware lost its count (a restart we did not see).
            # Retransmitting would run lines twice in the second case, so do nothing: a
            # firmware that kept its count asks again for the right line at the next
            # transmission.
            self._suspicious += 1
            if self._suspicious > self.config.max_resends:
                self._stop_reason = (
                    f"the firmware keeps asking for line {number} although it acknowledged "
                    f"line {self._acked_reliable}: it lost its line count (a restart without "
                    f"a start banner?)")
                self._failed = True
                raise StopStreaming
            self._note(f"ignored a resend request for line {number}, already acknowledged")
            return
        self._suspicious = 0
        order_error = self._error_kind == "line"
        self._error_kind = None
        if self._error_last_line == number - 1:
            # Error and Resend agree (a garbled reply would not): the firmware has every
            # line before the one it asks for.
            self._received = max(self._received, number - 1)
        self._error_last_line = None
        # Everything before the requested line has been accepted.
        while self._outstanding and self._outstanding[0].number < number:
            self._pop_front()
        self._set_acked(number - 1, reliable=False)
        pending = [s for s in self._outstanding if s.number == number]
        if order_error and pending:
            # A line out of sequence was refused while a transmission of the requested line
            # is unanswered. Marlin reads lines in the order sent, so: if the refused line was
            # sent before that transmission (a duplicate after a retransmission, or a line
            # behind an earlier refused one), that transmission is still on its way and
            # rewinding would put the host out of phase for good; if only later lines are
            # unanswered, the requested line was lost on the wire: rewind.
            # After a timeout, transmissions the host no longer tracks may still be answered
            # and the order tells nothing: wait a moment for the pending line's ok instead.
            # With nothing sent after the pending line (ping-pong, or the last line of the
            # file) the refused line is either an older transmission still being answered or
            # the pending line itself, its line number damaged on the wire: then no ok will
            # ever come for it. Waiting for the silence timeout instead hung the host for the
            # long timeout (30 min) when that line was a long command (M400, G28, M109...) and
            # for ever with a firmware that keeps talking. So the pending line gets a moment
            # to be acknowledged and is then retransmitted: if it had run after all, the
            # firmware refuses the copy (line numbers), and nothing runs twice.
            newest = pending[-1].seq
            older = [s for s in self._outstanding if s.number > number and s.seq < newest]
            newer = [s for s in self._outstanding if s.number > number and s.seq > newest]
            ghosts = newest <= self._timeout_seq + 2 * self.config.max_window
            if older or not newer or ghosts:
                if older:
                    self._outstanding.remove(older[0])
                    self._out_bytes -= older[0].size
                elif self._deferred is None:
                    self._deferred = (number, now + self.config.confirm_timeout)
                self._stale += 1
                return
        # The first transmission from the requested line on is the one refused.
        victim = None
        for i, sent in enumerate(self._outstanding):
            if sent.number >= number:
                victim = sent
                del self._outstanding[i]
                self._out_bytes -= sent.size
                break
        if number == self._max_sent + 1:
            self._next = max(self._next, number)
            return  # a duplicate was refused; nothing to retransmit
        if (number == self._rewind_target and victim is not None
                and victim.seq < self._rewind_seq):
            self._stale += 1
            return  # refused because an earlier line was: already being retransmitted
        self._rewind(number)

    def _rewind(self, number: int) -> None:
        """Retransmit from line ``number`` (a genuine resend request)."""
        self._deferred = None
        if number == self._last_genuine:
            self._genuine_count += 1
        else:
            self._last_genuine, self._genuine_count = number, 1
        if self._genuine_count > self.config.max_resends:
            self._stop_reason = (
                f"the firmware asked for line {number} {self._genuine_count} times in a row "
                f"(limit {self.config.max_resends}): the link is too noisy or the baud rate is "
                f"wrong")
            self._failed = True
            raise StopStreaming
        self._resends += 1
        self._rewind_target = number
        self._rewind_seq = self._seq + 1
        self._next = number

    def _on_error(self, text: str) -> None:
        if is_protocol_error(text):
            low = text.lower()
            # "Line Number is not Last Line Number+1": a line out of sequence was refused.
            self._error_kind = ("line" if "line number is not" in low or "expected line" in low
                                else "checksum")
            m = re.search(r"last line:?\s*(\d+)", low)
            self._error_last_line = int(m.group(1)) if m else None
            return  # a Resend follows
        low = text.lower()
        fatal = "halted" in low or "kill" in low or "stopped" in low or text.startswith("!!")
        # a firmware line can be anything up to the reader's 64 KiB: messages quote its start
        shown = text if len(text) <= 200 else text[:200] + "…"
        self._note(f"firmware error: {shown}")
        if fatal:
            self._stop_reason = f"the printer halted ({shown}); it needs a reset"
            self._fatal = self._failed = True
            raise StopStreaming
        policy = self.config.error_policy
        if policy == "ignore":
            return
        self._failed = True
        self._stop_reason = f"firmware error {excerpt(text, 200)} (error policy '{policy}')"
        if policy == "stop":
            self._emergency.set()
        self._cancel.set()

    def _on_restart(self) -> None:
        self._banner_seen = True
        if self._max_sent:
            self._restarted = True
            raise StopStreaming

    def _on_action(self, text: str) -> None:
        action = text.split(":", 1)[1].strip().split()[0].lower() if ":" in text else ""
        if action in ("pause", "paused"):
            self._note("the printer asked to pause")
            self.pause()
        elif action in ("resume", "resumed"):
            self._note("the printer asked to resume")
            self.resume()
        elif action == "cancel":
            self._note("the printer asked to cancel")
            self.cancel()

    def _on_silence(self, now: float, *, probe: bool = False) -> None:
        """Nothing heard for the timeout: retransmit from the first unacknowledged line.

        A ``probe`` (see :meth:`_probe_due`) retransmits the same way but does
        not count towards ``max_timeouts``: the firmware may only be busy.
        """
        first = self._acked + 1
        if probe:
            self._probed = first
            self.transcript.write("Note", f"a long command is silent: retransmitting from line "
                                          f"{first} in case it was lost")
        else:
            self._timeouts += 1
            self._timeouts_in_row += 1
        if self._timeouts_in_row > self.config.max_timeouts:
            self._stop_reason = (
                f"the printer stopped answering (no reply for "
                f"{self._timeouts_in_row} × {self._current_timeout():g} s)")
            self._failed = True
            raise StopStreaming
        if not probe:
            self.transcript.write("Note", f"timeout: retransmitting from line {first}")
        self._timeout_seq = self._seq
        self._outstanding.clear()
        self._out_bytes = 0
        self._resend_oks = 0
        self._rewind_target = first
        self._rewind_seq = self._seq + 1
        self._next = min(self._next, first)

    def _on_busy(self, now: float) -> None:
        if self._last_busy is not None:
            self._keepalive_gap = max(self._keepalive_gap, now - self._last_busy)
        self._last_busy = now
        self._keepalive_seen = True

    def _on_m113(self, text: str) -> None:
        """The file sets the keepalive interval (``M113 S<s>``; ``S0`` turns it off)."""
        m = _M113_S.search(text)
        if m is None:
            return
        seconds = float(m.group(1))
        self._keepalive_off = seconds <= 0
        if seconds > 0:
            self._keepalive_interval = seconds

    def _current_timeout(self) -> float:
        """Silence after which the lines in flight are taken as unanswered, s.

        A long command (homing, heating, a dwell, M400) may keep a firmware
        silent for minutes, so it gets ``long_timeout``, unless the firmware has
        shown that it says ``busy:`` while it works: then silence for a few
        keepalive intervals means that the line or its ``ok`` was lost, and
        waiting ``long_timeout`` for it (30 min) would only look like a hang.
        Retransmitting is safe either way: a line that did arrive is refused as
        a duplicate (line numbers).
        """
        if not any(s.long for s in self._outstanding):
            return self.config.reply_timeout
        if self._keepalive_known() and not (any(s.heating for s in self._outstanding)
                                            and self._autoreport_seen
                                            and not self._wait_reports_marked):
            # (A heating wait whose reports cannot be told from auto-reports keeps the long
            # timeout: its silence is not seen.)
            return self._keepalive_limit()
        return self.config.long_timeout

    def _keepalive_known(self) -> bool:
        return ((self._keepalive_seen or self.firmware.busy_protocol)
                and not self._keepalive_off)

    def _keepalive_limit(self) -> float:
        return min(self.config.long_timeout,
                   max(self.config.reply_timeout, self.config.keepalive_timeout,
                       3.0 * self._keepalive_gap, 4.0 * self._keepalive_interval))

    def _probe_due(self, now: float) -> bool:
        """A long command has been silent for the keepalive limit, and the firmware has not
        shown whether it sends keepalives: retransmit once, uncounted.

        The line may have been lost on the wire, and without this the host would
        wait ``long_timeout`` (30 min) to find out; if the firmware is only busy
        (no keepalive), it refuses the copy as a duplicate when it reads it.
        Klipper does not check line numbers, so it never gets a copy.
        """
        return (self._probed != self._acked + 1
                and now >= self._last_rx + self._keepalive_limit()
                and any(s.long for s in self._outstanding)
                and not self._keepalive_known()
                and self.firmware.checks_line_numbers)

    def _take_waiting(self) -> None:
        """Handle every reply already received, before transmitting.

        A duplicated ``ok`` usually arrives right behind the first one; handled
        now, it finds nothing outstanding and is dropped, instead of being taken
        for the ``ok`` of the next line (which would let the host run ahead).
        """
        for _ in range(_MAX_WAITING):
            if not (self._reader.pending() or self._port.in_waiting):
                return
            text = self._readline(0.0)
            if text is None:
                return
            self._handle(parse_reply(text), time.monotonic())

    def _pump_once(self, more: Callable[[], bool], allow_new: bool) -> None:
        """Transmit what the window allows, then handle at most a few replies."""
        self._take_waiting()
        now = time.monotonic()
        if self._deferred is not None:
            number, due = self._deferred
            if self._acked >= number:
                self._deferred = None
            elif now >= due:
                # The line a refusal asked for never got its ok: it was lost after all.
                for sent in list(self._outstanding):
                    if sent.number >= number:
                        self._outstanding.remove(sent)
                        self._out_bytes -= sent.size
                        break
                self._rewind(number)
        while self._next < len(self._frames) or (allow_new and more()):
            if not self._can_transmit(len(self._frames[self._next])):
                break
            self._transmit(self._next)
        now = time.monotonic()
        deadline = self._last_rx + self._current_timeout()
        if self._resend_oks:
            deadline = min(deadline, self._resend_ok_deadline)
        if self._deferred is not None:
            deadline = min(deadline, self._deferred[1])
        text = self._readline(min(deadline, now + 0.1))
        now = time.monotonic()
        if text is not None:
            self._handle(parse_reply(text), now)
            return
        if self._resend_oks and now >= self._resend_ok_deadline:
            # The firmware sent Resend without ok: do as if it had.
            self._resend_oks -= 1
            return
        if self._outstanding and now >= self._last_rx + self._current_timeout():
            self._on_silence(now)
            self._last_rx = now
        elif self._outstanding and self._probe_due(now):
            self._on_silence(now, probe=True)
            self._last_rx = now
        elif not self._outstanding:
            self._last_rx = now
