"""Binary G-code streamed to a printer (issue #28): ``load_program``/``parse_program`` and
``printability stream`` send the commands of the G-code a ``.bgcode`` file holds, exactly as
those of the same G-code as text (same commands, same order, comments left out); the memory
guard counts the decoded text; a damaged file is a one-paragraph error and nothing is sent."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from bg_helpers import CONFIG_IDS, CONFIGS, PRUSA_DEFAULT, binarize

import simulators  # noqa: F401  (registers printsim://)
from gcode.bgcode import decode_bgcode
from machine_io import Host, HostConfig, executed_as_streamed, load_program, parse_program
from machine_io.program import MEATPACK_EXPANSION, program_memory
from printability.errors import FileFormatError, ResourceError

sys.path.append(str(Path(__file__).resolve().parents[1] / "machine_io"))
from _fake_marlin import FakeMarlin

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
FAST = dict(reply_timeout=0.3, banner_timeout=0.5, handshake_timeout=1.0, confirm_timeout=0.2,
            resend_ok_timeout=0.3, reconnect_timeout=10.0)
QUERIES = ("M115", "M114", "M105")


@pytest.fixture
def files(sample_text, sample_binary, tmp_path):
    """The short PrusaSlicer sample as text and as PrusaSlicer's binary G-code."""
    text, binary = tmp_path / "part.gcode", tmp_path / "part.bgcode"
    text.write_bytes(sample_text("short"))
    binary.write_bytes(sample_binary("short", *PRUSA_DEFAULT))
    return text, binary


def _stream_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "printability", "stream", *args],
                       capture_output=True, text=True, timeout=timeout, env=ENV, cwd=ROOT)
    r.stderr = " ".join(r.stderr.split())  # the error paragraph is wrapped for a terminal
    return r


# ----------------------------------------------------------------- the program


@pytest.mark.parametrize(("compression", "encoding"), CONFIGS, ids=CONFIG_IDS)
def test_the_program_is_that_of_the_text(sample_text, sample_binary, tmp_path, compression,
                                         encoding):
    text = sample_text("short")
    data = sample_binary("short", compression, encoding)
    expected = parse_program(text, source="part.gcode")
    assert len(expected) > 900
    got = parse_program(data, source="part.bgcode")
    assert got.commands == expected.commands and got.seconds == expected.seconds
    assert got.axes == expected.axes
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    loaded = load_program(f)
    assert loaded.commands == expected.commands and loaded.source == str(f)
    # lines of the decoded G-code (no thumbnails, no header comments): the command there
    lines = decode_bgcode(data).gcode.splitlines()
    for i in (0, 100, len(loaded) - 1):
        line = lines[loaded.source_lines[i] - 1].split(b";")[0].strip().decode()
        assert line == loaded.commands[i]


@pytest.mark.parametrize("name", ["part.gcode", "part.txt", "part"])
def test_binary_gcode_is_recognised_whatever_its_name(files, tmp_path, name):
    text, binary = files
    other = tmp_path / name
    other.write_bytes(binary.read_bytes())
    assert load_program(other).commands == load_program(text).commands


def test_blocks_cut_anywhere_give_the_same_lines(sample_text):
    # libbgcode cuts its blocks at line ends; a block ending inside a line (or between \r
    # and \n) must not change the lines either
    from machine_io.program import _chunk_lines

    text = sample_text("short").replace(b"\n", b"\r\n")
    for size in (1, 7, 4096):
        pieces = [text[i:i + size] for i in range(0, len(text), size)]
        assert list(_chunk_lines(pieces)) == text.splitlines()


# ----------------------------------------------------------------- memory


@pytest.mark.parametrize(("compression", "encoding"), CONFIGS, ids=CONFIG_IDS)
def test_the_memory_estimate_counts_the_decoded_text(sample_binary, tmp_path, compression,
                                                     encoding):
    data = sample_binary("short", compression, encoding)
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    doc = decode_bgcode(data)
    need = program_memory(f)
    # decoding holds the file twice and the text twice; the text is bounded from the headers
    assert need >= 2 * len(data) + 2 * len(doc.gcode)
    bound = sum(b.uncompressed_size * (MEATPACK_EXPANSION if b.encoding else 1)
                for b in doc.gcode_blocks)
    assert need == 2 * len(data) + 2 * bound
    if compression:
        assert need > 4 * len(data)  # far more than the compressed size says


def test_a_binary_file_too_big_for_memory_is_refused_before_it_is_decoded(files):
    _, binary = files
    with pytest.raises(ResourceError) as e:
        load_program(binary, max_memory=2 * binary.stat().st_size)
    message = " ".join(str(e.value).split())
    assert message.startswith(f"{binary}: reading this binary G-code file for streaming")
    assert "by its block headers, its G-code decodes to at most 0.1 MiB of text" in message
    assert "nothing was sent" in message and "as text G-code" in message


def test_a_binary_file_too_big_once_decoded_is_refused(tmp_path):
    # deflate without MeatPack: the headers state the text exactly; with short lines the
    # program (the text plus 24 bytes a line) outgrows the decoding
    data = binarize(b"G28\n" + b"".join(b"G1 X%d\n" % (i % 10) for i in range(20000)), 1, 0)
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    decoding = program_memory(f)
    text = decode_bgcode(data).gcode
    program = 2 * len(text) + 24 * (text.count(b"\n") + 1)
    assert program > decoding
    with pytest.raises(ResourceError) as e:
        load_program(f, max_memory=decoding)
    message = " ".join(str(e.value).split())
    assert f"its G-code is {len(text) / 2**20:.1f} MiB of text once decoded" in message
    assert "nothing was sent" in message
    assert len(load_program(f, max_memory=program)) == 20001


@pytest.mark.parametrize("how", ["crc", "truncated"])
def test_a_damaged_binary_file_is_refused(sample_binary, tmp_path, how):
    data = sample_binary("short", *PRUSA_DEFAULT)
    g = decode_bgcode(data).gcode_blocks[0]
    if how == "crc":
        bad = bytearray(data)
        bad[g.data + 100] ^= 0x40
        data, said = bytes(bad), "fails its CRC32 check"
    else:
        data, said = data[:g.start + 50], "the file is cut off in G-code block"
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    for load in (lambda: load_program(f), lambda: parse_program(data, source=str(f))):
        with pytest.raises(FileFormatError) as e:
            load()
        assert str(e.value).startswith(f"{f}: damaged binary G-code (.bgcode)")
        assert said in str(e.value)


# ----------------------------------------------------------------- the simulator


def _stream_simulated(url: str, program) -> tuple[object, list[str]]:
    """Stream ``program`` to the in-process simulator (as tests/machine_io's
    test_host_simulator does); the report and the numbered commands it executed."""
    with Host(url, config=HostConfig(**FAST)) as host:
        host.connect()
        report = host.stream(program)
        firmware = host._port.simulator.firmware
    return report, [t for n, t in firmware.executed if n is not None and not t.startswith("M110")]


@pytest.mark.parametrize("faults", ["", "corrupt~0.01,busy~0.01,drop-ok~0.005"])
@pytest.mark.parametrize(("compression", "encoding"), [PRUSA_DEFAULT, (1, 0), (0, 1)],
                         ids=["hs12-meatpack_comments", "deflate-plain", "none-meatpack"])
def test_the_simulator_executes_the_same_commands(sample_text, sample_binary, tmp_path,
                                                  compression, encoding, faults):
    text, binary = tmp_path / "part.gcode", tmp_path / "part.bgcode"
    text.write_bytes(sample_text("short"))
    binary.write_bytes(sample_binary("short", compression, encoding))
    url = "printsim://?profile=marlin-advanced&seed=3" + (f"&faults={faults}" if faults else "")
    runs = []
    for path in (text, binary):
        program = load_program(path)
        report, executed = _stream_simulated(url, program)
        assert report.completed, report.stopped
        assert executed_as_streamed(executed, list(program.commands), report)
        runs.append(executed)
    assert len(runs[0]) > 900 and runs[1] == runs[0]


def test_the_cli_streams_a_binary_file_to_the_fake_marlin(files, tmp_path):
    text, binary = files
    printed = []
    for path in (text, binary):
        out = tmp_path / f"{path.suffix[1:]}.json"
        with FakeMarlin(faults={10: ["corrupt"], 50: ["dup_ok"]}) as fw:
            r = _stream_cli(str(path), "--port", fw.path, "--timeout", "0.5", "--no-progress",
                            "--json", str(out))
        assert r.returncode == 0, r.stderr
        n = len(load_program(text))
        assert f"printed {path}: {n} of {n} commands" in r.stdout
        assert json.loads(out.read_text())["acknowledged"] == n
        printed.append([c for c in fw.executed if not c.startswith(QUERIES)])
    assert printed[1] == printed[0] == list(load_program(text).commands)


def _simulate_and_stream(path: Path, log: Path) -> tuple[str, str]:
    """Start ``printability simulate``, stream ``path`` to it with the real CLI, stop it: the
    simulator's stderr and the stream's stdout (as tests/simulators/test_simulate_status)."""
    sim = subprocess.Popen([sys.executable, "-m", "printability", "simulate", "--pty", "--clock",
                            "sim", "--duration", "300", "--quiet"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                           env=ENV)
    try:
        port = sim.stdout.readline()
        assert port.startswith("/dev/"), sim.stderr.read()
        r = _stream_cli(str(path), "--port", port.strip(), "--no-progress", "--log", str(log),
                        timeout=300)
        assert r.returncode == 0, r.stderr
        sim.send_signal(signal.SIGTERM)
        _, err = sim.communicate(timeout=30)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert sim.returncode == 0, err
    return err, r.stdout


def test_the_cli_streams_a_binary_file_to_the_simulator(files, tmp_path):
    """The built-in simulator, through the real entry points: the same lines go on the wire
    (numbered and checksummed alike) and it executes as many commands."""
    sent, summaries = [], []
    for path in files:
        log = tmp_path / f"{path.suffix[1:]}.log"
        err, out = _simulate_and_stream(path, log)
        n = len(load_program(files[0]))
        assert f"printed {path}: {n} of {n} commands" in out
        summaries.append(re.search(r"(\d+) commands executed, (\d+) resends", err).groups())
        sent.append([line.split("Send: ", 1)[1] for line in log.read_text().splitlines()
                     if "Send: N" in line])
    assert len(sent[0]) > 900 and sent[1] == sent[0]
    assert summaries[1] == summaries[0]


@pytest.mark.parametrize("how", ["crc", "truncated"])
def test_the_cli_refuses_a_damaged_binary_file_and_sends_nothing(sample_binary, tmp_path,
                                                                 how):
    data = sample_binary("short", *PRUSA_DEFAULT)
    g = decode_bgcode(data).gcode_blocks[0]
    if how == "crc":
        bad = bytearray(data)
        bad[g.data + 100] ^= 0x40
        data, said = bytes(bad), (f"G-code block {g.index + 1} (byte {g.start}) fails its "
                                  "CRC32 check")
    else:
        data, said = data[:g.start + 50], (f"the file is cut off in G-code block "
                                           f"{g.index + 1} (byte {g.start})")
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    with FakeMarlin() as fw:
        r = _stream_cli(str(f), "--port", fw.path, "--no-progress")
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.startswith("printability: error:") and "Traceback" not in r.stderr
    assert r.stderr.count("printability: error:") == 1
    assert "part.bgcode: damaged binary G-code (.bgcode)" in r.stderr and said in r.stderr
    assert fw.received == []  # refused before the handshake: nothing of the file was sent
