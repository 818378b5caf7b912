"""Fault injection for the serial host's tests.

A fault spec is a comma-separated list of items::

    KIND@LINE[:ARG]     scheduled: fires once, at the host's line number LINE
    KIND~RATE[:ARG]     random: fires on each received line with probability RATE

KIND is one of :data:`printability.options.FAULT_KINDS`; ARG is the stall
duration in seconds (``stall``, default 2), the number of resend requests
(``resend_storm``, default 5) or of spurious busy lines (``busy``, default 1).
For lines without a line number, LINE counts received command lines from 1.

Random faults draw from one ``random.Random(seed)`` in the order lines are
received, so a seed reproduces the same faults for the same byte stream.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from printability.base.errors import InputError
from printability.base.options import FAULT_KINDS

__all__ = ["Fault", "FaultInjector", "FaultPlan"]

_DEFAULT_ARG = {"stall": 2.0, "resend-storm": 5.0, "busy": 1.0}


@dataclass(frozen=True)
class Fault:
    """One fault.

    Attributes
    ----------
    kind
        From :data:`printability.options.FAULT_KINDS`.
    line
        Host line number it is scheduled at, or None for a random fault.
    rate
        Probability per received line (random faults), in [0, 1].
    arg
        Stall seconds, storm length or busy count.
    """

    kind: str
    line: int | None = None
    rate: float = 0.0
    arg: float = 0.0


@dataclass(frozen=True)
class FaultPlan:
    """The faults of one simulator run and the seed of the random ones."""

    faults: tuple[Fault, ...] = ()
    seed: int = 0

    @classmethod
    def parse(cls, spec: str, *, seed: int = 0) -> FaultPlan:
        """Parse a fault spec (see the module docstring).

        Raises
        ------
        InputError, UnknownOptionError
        """
        out = []
        for item in filter(None, (s.strip() for s in (spec or "").split(","))):
            if "@" in item:
                kind, _, rest = item.partition("@")
            elif "~" in item:
                kind, _, rest = item.partition("~")
            else:
                raise InputError(f"fault {item!r}: expected KIND@LINE or KIND~RATE, e.g. "
                                 f"'drop-ok@12' or 'corrupt~0.01'")
            kind = FAULT_KINDS.check(kind)
            when, _, arg_text = rest.partition(":")
            arg = _DEFAULT_ARG.get(kind, 0.0)
            if arg_text:
                try:
                    arg = float(arg_text)
                except ValueError:
                    arg = math.nan
                if not (math.isfinite(arg) and arg >= 0):
                    raise InputError(f"fault {item!r}: the value after ':' must be a "
                                     f"non-negative number; found {arg_text!r}")
            try:
                if "@" in item:
                    out.append(Fault(kind, line=int(when), arg=arg))
                else:
                    rate = float(when)
                    if not (0.0 <= rate <= 1.0):
                        raise ValueError
                    out.append(Fault(kind, rate=rate, arg=arg))
            except ValueError:
                raise InputError(f"fault {item!r}: expected an integer line after '@' or a "
                                 f"probability in [0, 1] after '~'; found {when!r}") from None
        return cls(tuple(out), int(seed))

    def __str__(self) -> str:
        parts = []
        for f in self.faults:
            where = f"@{f.line}" if f.line is not None else f"~{f.rate:g}"
            parts.append(f"{f.kind}{where}:{f.arg:g}")
        return ",".join(parts)


class FaultInjector:
    """Decides, line by line, which faults fire (deterministic for a seed)."""

    def __init__(self, plan: FaultPlan) -> None:
        self.plan = plan
        self._rng = random.Random(plan.seed)
        self._fired: set[int] = set()
        self.log: list[tuple[str, int]] = []

    def reset_rng(self) -> None:
        self._rng = random.Random(self.plan.seed)
        self._fired.clear()
        self.log.clear()

    def draw(self, line: int) -> list[Fault]:
        """Faults that fire for the received line numbered ``line``."""
        hits = []
        for i, f in enumerate(self.plan.faults):
            if f.line is not None:
                if f.line == line and i not in self._fired:
                    self._fired.add(i)
                    hits.append(f)
            elif f.rate > 0 and self._rng.random() < f.rate:
                hits.append(f)
        for f in hits:
            self.log.append((f.kind, line))
        return hits

    def corrupt(self, data: bytes) -> bytes:
        """Flip one bit of one byte (never producing a line break)."""
        if not data:
            return data
        b = bytearray(data)
        for _ in range(8):
            i = self._rng.randrange(len(b))
            v = b[i] ^ (1 << self._rng.randrange(7))
            if v not in (10, 13):
                b[i] = v
                break
        return bytes(b)
