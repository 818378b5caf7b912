"""LineReader: lines from a POSIX port read straight from its descriptor, and writes."""

from __future__ import annotations

import os
import pty
import threading
import time
import tty

import pytest
import serial

from machine_io.transport import LineReader, open_port


@pytest.fixture
def pair():
    master, slave = pty.openpty()
    tty.setraw(slave)
    port = open_port(os.ttyname(slave), timeout=0.05)
    os.close(slave)
    yield master, port
    port.close()
    try:
        os.close(master)
    except OSError:
        pass


def test_lines_split_across_reads_and_blank_lines_skipped(pair):
    master, port = pair
    reader = LineReader(port)
    assert reader._fd is not None  # the descriptor path is the one under test
    os.write(master, b"ok\r\nT:20")
    assert reader.readline(time.monotonic() + 1) == b"ok"
    assert reader.readline(time.monotonic() + 0.1) is None  # half a line
    os.write(master, b"0.0 /0.0\n\n\nok N3 P15 B3\n")
    assert reader.readline(time.monotonic() + 1) == b"T:200.0 /0.0"
    assert reader.pending()
    assert reader.readline(time.monotonic() + 1) == b"ok N3 P15 B3"


def test_write_reaches_the_other_end_whole(pair):
    master, port = pair
    reader = LineReader(port)
    data = b"".join(b"N%d G1 X1.000 Y2.000 E0.1*99\n" % i for i in range(2000))  # > pty buffer
    got = bytearray()
    t = threading.Thread(target=reader.write, args=(data,))
    t.start()
    while len(got) < len(data):
        got += os.read(master, 65536)
    t.join(5)
    assert bytes(got) == data


def test_a_vanished_port_is_a_serial_error(pair):
    master, port = pair
    reader = LineReader(port)
    os.close(master)
    with pytest.raises(serial.SerialException):
        for _ in range(3):
            reader.readline(time.monotonic() + 0.2)
