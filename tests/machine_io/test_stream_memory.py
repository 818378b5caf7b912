"""The host forgets lines long acknowledged: a print of millions of lines does not keep each
one's frame and text to the end (issue #24, item 1: bounded memory)."""

from __future__ import annotations

import pytest
from _fake_marlin import FakeMarlin

import machine_io.resend as resend_module
from machine_io import Host, HostConfig, parse_program
from machine_io.resend import _History

FAST = dict(reply_timeout=0.4, banner_timeout=0.3, handshake_timeout=0.5, resend_ok_timeout=0.2,
            reconnect_timeout=0)
QUERIES = ("M115", "M114", "M105")


def test_history_keeps_numbers_and_forgets_the_head():
    h = _History(b"")
    for n in range(1, 10):
        h.append(n)
    h.forget_before(6)
    assert len(h) == 10 and h[6] == 6 and h[9] == 9
    with pytest.raises(IndexError):
        h[5]
    del h[8:]
    assert len(h) == 8
    with pytest.raises(IndexError):
        del h[3:]


@pytest.mark.parametrize("advanced", [False, True], ids=["plain-ok", "advanced-ok"])
def test_a_long_print_keeps_a_bounded_history(monkeypatch, advanced):
    monkeypatch.setattr(resend_module, "_KEEP_BEHIND", 40)
    p = parse_program("\n".join(f"G1 X{i % 90}.5 Y{i % 31} E{i}" for i in range(1500)).encode(),
                      source="long.gcode")
    kept = []
    faults = {300: ["corrupt"], 301: ["drop"], 900: ["drop_ok"], 1400: ["corrupt"]}
    with FakeMarlin(advanced_ok=advanced, faults=faults) as fw, \
            Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(p, on_progress=lambda _: kept.append(len(host._frames._items)))
        assert host._frames._base > 1000  # the head was forgotten
    assert report.completed
    assert [c for c in fw.executed if not c.startswith(QUERIES)] == list(p.commands)
    assert max(kept) <= 2 * 40 + 64


def test_a_resend_of_a_forgotten_line_is_ignored(monkeypatch):
    monkeypatch.setattr(resend_module, "_KEEP_BEHIND", 10)
    p = parse_program("\n".join(f"G1 X{i}" for i in range(200)).encode(), source="r.gcode")
    with FakeMarlin() as fw, Host(fw.path, config=HostConfig(**FAST)) as host:
        host.connect()
        host.stream(p)
        host._reset_counters()
        for _ in range(100):
            host._append("G1 X1", 0)
        host._acked = host._max_sent = 90
        host._append("G1 X1", 0)  # forgets the lines before 80
        host._on_resend(3, 0.0)
    assert any("already acknowledged" in e for e in host._events)
