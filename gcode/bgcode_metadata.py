"""Binary G-code (``.bgcode``) metadata: ``key=value`` blocks read, updated and rescaled."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

__all__ = ["parse_ini", "rescaled_metadata", "updated_ini"]

def parse_ini(text: str) -> tuple[tuple[str, str], ...]:
    """``key=value`` lines (the first ``=`` splits; other lines are skipped)."""
    pairs = []
    for line in text.split("\n"):
        k, eq, v = line.partition("=")
        if eq:
            pairs.append((k, v))
    return tuple(pairs)


def updated_ini(pairs: Sequence[tuple[str, str]], updates: Mapping[str, str]) -> bytes:
    """The INI text of ``pairs`` with the values of ``updates`` (new keys appended)."""
    seen = set()
    lines = []
    for k, v in pairs:
        if k in updates:
            v = updates[k]
            seen.add(k)
        lines.append(f"{k}={v}\n")
    lines.extend(f"{k}={v}\n" for k, v in updates.items() if k not in seen)
    return "".join(lines).encode("utf-8")


_TIME_KEYS = ("estimated printing time (normal mode)", "estimated printing time (silent mode)")
_FILAMENT_KEYS = ("filament used [mm]", "filament used [cm3]", "filament used [g]",
                  "filament cost", "total filament used [g]", "total filament cost")
_DHMS = re.compile(r"^\s*(?:(\d+)d\s*)?(?:(\d+)h\s*)?(?:(\d+)m\s*)?(?:(\d+)s)?\s*$")
_NUMBER = re.compile(r"-?\d+(?:\.(\d+))?")


def _dhms(seconds: float) -> str:
    """PrusaSlicer's way of writing a duration: ``1d 2h 3m 4s``, ``2h 3m 4s``, ``3m 4s``,
    ``4s``."""
    s = max(0, round(seconds))
    d, s = divmod(s, 86400)
    h, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    if d:
        return f"{d}d {h}h {m}m {s}s"
    if h:
        return f"{h}h {m}m {s}s"
    return f"{m}m {s}s" if m else f"{s}s"


def _scaled_time(value: str, factor: float) -> str | None:
    m = _DHMS.match(value)
    if m is None or not any(m.groups()):
        return None
    d, h, mi, s = (int(g or 0) for g in m.groups())
    return _dhms((((d * 24 + h) * 60 + mi) * 60 + s) * factor)


def _scaled_numbers(value: str, factor: float) -> str:
    """Every number of ``value`` (a per-extruder list ``1.50, 0.00``) times ``factor``,
    written with as many decimals as it had."""
    def one(m: re.Match) -> str:
        decimals = len(m.group(1) or "")
        return f"{float(m.group(0)) * factor:.{decimals}f}"

    return _NUMBER.sub(one, value)


def rescaled_metadata(pairs: Sequence[tuple[str, str]], *, time_factor: float | None = None,
                      filament_factor: float | None = None) -> dict[str, str]:
    """New values of the metadata PrusaSlicer derives from the G-code, scaled.

    ``estimated printing time (normal|silent mode)`` are multiplied by ``time_factor`` (the
    ratio of the print times of the new and the old G-code, on any one model) and written
    as PrusaSlicer writes them; ``filament used [mm|cm3|g]``, ``filament cost`` and ``total
    filament used [g]`` / ``total filament cost`` by ``filament_factor`` (the ratio of the
    filament the extruding moves push), keeping their decimals. The first-layer times and
    the wipe tower's share are left as they are (no per-layer or per-feature estimate).

    Parameters
    ----------
    pairs
        A metadata block's ``(key, value)`` pairs.
    time_factor, filament_factor
        None: leave those keys alone.

    Returns
    -------
    dict
        Only the keys whose value changes.
    """
    out: dict[str, str] = {}
    for k, v in pairs:
        new = None
        if time_factor is not None and k in _TIME_KEYS:
            new = _scaled_time(v, time_factor)
        elif filament_factor is not None and k in _FILAMENT_KEYS:
            new = _scaled_numbers(v, filament_factor)
        if new is not None and new != v:
            out[k] = new
    return out
