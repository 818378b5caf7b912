"""A printer that keeps talking without ever answering (issue #24, item 2): every wait of the
connection ends, at the latest at ``connect_timeout``, with a message that says what was heard
and that nothing of the file was sent."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import time
import tty

import pytest
from _noisy_peer import BOOT_LOOP, NOISE, NoisyPeer

from machine_io import Host, HostConfig
from machine_io.transport import MAX_LINE, LineReader, open_port
from printability.errors import InputError, PrinterError

# Without the overall deadline these attempts alone would wait 1000 × 0.5 s.
ENDLESS = dict(banner_timeout=0.2, handshake_timeout=0.5, handshake_attempts=1000)


def test_noise_for_ever_ends_at_the_connect_timeout():
    with NoisyPeer(NOISE) as peer, \
            Host(peer.path, config=HostConfig(connect_timeout=1.5, **ENDLESS)) as host:
        t0 = time.monotonic()
        with pytest.raises(PrinterError) as e:
            host.connect()
        elapsed = time.monotonic() - t0
    message = " ".join(str(e.value).split())
    assert elapsed < 6, elapsed
    assert "did not complete the connection within 1.5 s" in message
    assert "nothing of the file was sent" in message
    assert "line(s)" in message and "the last '" in message  # what it heard
    assert len(message) < 1000
    # only handshakes went out
    sent = [line for line in bytes(peer.received).split(b"\n") if line]
    assert sent and all(b"M110" in line for line in sent)


def test_a_board_in_a_boot_loop_is_named_as_such():
    with NoisyPeer(BOOT_LOOP, interval=0.02) as peer, \
            Host(peer.path, config=HostConfig(banner_timeout=0.3, handshake_timeout=0.4,
                                              handshake_attempts=3)) as host:
        with pytest.raises(PrinterError) as e:
            host.connect()
    message = " ".join(str(e.value).split())
    assert "talked but never acknowledged 'M110 N0'" in message
    assert "restarted" in message and "nothing of the file was sent" in message


def test_a_reconnection_handshake_has_the_same_deadline():
    # the handshake alone (a new stream's, a reconnection's) is a connection too
    with NoisyPeer(NOISE) as peer, \
            Host(peer.path, config=HostConfig(connect_timeout=1.0, **ENDLESS)) as host:
        host.open()
        t0 = time.monotonic()
        with pytest.raises(PrinterError, match="within 1 s"):
            host._handshake(41)
        assert time.monotonic() - t0 < 5


def test_connect_timeout_is_validated():
    with pytest.raises(InputError, match="connect_timeout"):
        HostConfig(connect_timeout=-1)


def test_noise_without_line_ends_is_handed_out_in_bounded_pieces():
    master, slave = pty.openpty()
    tty.setraw(slave)
    port = open_port(os.ttyname(slave), timeout=0.05)
    try:
        reader = LineReader(port)
        blob = b"\xaa" * (3 * MAX_LINE)
        for k in range(0, len(blob), 4096):
            os.write(master, blob[k:k + 4096])
            while (line := reader.readline(time.monotonic() + 0.05)) is not None:
                assert len(line) <= MAX_LINE + 4096
        assert len(reader._buffer) <= MAX_LINE
    finally:
        port.close()
        os.close(slave)
        os.close(master)


def test_stream_command_gives_up_at_connect_timeout(tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G28\nG1 X1 Y1\n")
    with NoisyPeer(NOISE) as peer:
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, "-m", "printability", "stream", str(gcode),
                            "--port", peer.path, "--connect-timeout", "2", "--no-progress"],
                           capture_output=True, text=True, timeout=60)
        elapsed = time.monotonic() - t0
    stderr = " ".join(r.stderr.split())
    assert r.returncode == 1, r.stderr
    assert stderr.startswith("printability: error:") and "Traceback" not in stderr
    assert "within 2 s (--connect-timeout)" in stderr and "nothing of the file was sent" in stderr
    assert elapsed < 30
    assert b"G1 X1" not in bytes(peer.received)
