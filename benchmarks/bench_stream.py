"""Streaming throughput: printability's host vs Printrun's printcore, same simulator, same wire.

The virtual printer runs on a pty with the real clock and paces its wire at
250 000 baud (10 bits per byte, both directions). Motion is made instantaneous
(huge acceleration and feed) so the wire and the hosts are what is measured,
not the planner. Each host streams the same G-code (real-looking moves of
~35 bytes once framed) to a fresh simulator:

- printability, ping-pong, to a Marlin profile (plain ``ok``);
- printability, send-ahead, to a Marlin profile with ADVANCED_OK (``ok N P B``);
- Printrun's printcore (ping-pong), to the plain Marlin profile.

The wire's line rate is what the host-to-printer direction can carry:
``baud / 10 / bytes per framed line``. Ping-pong cannot reach it exactly: each
line waits for its ``ok`` (3 more bytes on the return wire) and the turnaround
of both ends. Results are printed as lines/s and as a fraction of the line rate,
side by side, from one run; no timing is asserted anywhere.

The ping-pong ceiling: even with hosts and printers that cost nothing, each
line takes its own wire time, the ``ok``'s (3 bytes) and one round trip
through the pseudo-terminal (the kernel hands pty bytes over in a worker, some
tens of µs each way; it is measured here first, between two processes that do
nothing else). ``of ceiling`` divides by that.

Run::

    python benchmarks/bench_stream.py [--lines 20000] [--baud 250000]

Printrun is installed with ``pip install --no-deps printrun`` (its printcore
needs only pyserial).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import pty
import random
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tty

from machine_io import Host, HostConfig, checksum, frame, parse_program

FAST_MOTION = {"acceleration": 1e9, "max_feed_xy": 1e9, "max_feed_e": 1e9, "max_feed_z": 1e9,
               "max_feed_rotary": 1e9, "rotary_acceleration": 1e9, "junction_deviation": 1.0}


def make_gcode(n: int, seed: int = 1) -> list[str]:
    """``n`` extrusion moves like a slicer's (coordinates with 3 decimals, E with 5)."""
    rng = random.Random(seed)
    # Cold extrusion allowed (no heating in a bench); a feed rate no move ever reaches.
    lines = ["G90", "M83", "G92 E0", "M302 P1", "G1 F60000000"]
    for _ in range(n - len(lines)):
        lines.append(f"G1 X{rng.uniform(20, 200):.3f} Y{rng.uniform(20, 200):.3f} "
                     f"E{rng.uniform(0.01, 0.9):.5f}")
    return lines


def start_sim(profile: str, baud: int, record: str):
    """``printability simulate`` in its own process (as a user runs it); returns (proc, port)."""
    fw = [f"--fw={k}={v}" for k, v in FAST_MOTION.items()]
    proc = subprocess.Popen([sys.executable, "-m", "printability", "simulate", "--pty",
                             "--clock", "real", "--baud", str(baud), "--machine", "xy",
                             "--profile", profile, "--record", record, *fw],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = proc.stdout.readline().strip()
    if not port:
        raise RuntimeError(f"the simulator did not start: {proc.stderr.read()}")
    return proc, port


def _wait_until(t: float) -> None:
    while (left := t - time.perf_counter()) > 0:
        if left > 0.002:
            time.sleep(left - 0.001)


def _paced_responder(baud: int, advanced: bool, q, stop) -> None:
    """A minimal Marlin-like responder on a pty (runs in its own process): a wire paced at
    ``baud`` in each direction and no firmware work at all.

    Each line "arrives" 10 bits per byte after the inbound wire was free, is
    checked (line number and checksum, else ``Resend``) and answered ``ok`` (or
    ``ok N P B`` with ADVANCED_OK), the reply written once it has crossed the
    return wire (full duplex: replies never hold up the inbound wire). It shows
    what each host reaches when the printer costs nothing. Waits for a reply
    due within 0.3 ms spin, for sub-millisecond accuracy.
    """
    master, slave = pty.openpty()
    tty.setraw(slave)
    q.put(os.ttyname(slave))
    lines: list[str] = []
    buf, wire_in, wire_out, last = b"", 0.0, 0.0, 0
    replies: list[tuple[float, bytes]] = []  # (due, bytes), in order
    os.write(master, b"start\n")
    while not stop.is_set():
        wait = 0.05 if not replies else max(0.0, replies[0][0] - time.perf_counter() - 0.0003)
        r, _, _ = select.select([master], [], [], wait)
        if r:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            now = time.perf_counter()
            buf += data
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                wire_in = max(wire_in, now) + (len(raw) + 1) * 10 / baud
                text = raw.decode(errors="replace").strip()
                reply = "ok"
                if text.startswith("N"):
                    body, _, cs = text.rpartition("*")
                    n = int(body.split(" ", 1)[0][1:])
                    if cs.isdigit() and int(cs) == checksum(body.encode()) and (
                            n == last + 1 or "M110" in body):
                        last = n
                        cmd = body.split(" ", 1)[1]
                        if not cmd.startswith(("M110", "M105")):  # handshake, end barrier
                            lines.append(cmd)
                        if advanced:
                            reply = f"ok N{n} P15 B3"
                    else:
                        reply = (f"Error:checksum mismatch, Last Line: {last}\n"
                                 f"Resend: {last + 1}\nok")
                elif text.startswith("M115"):
                    reply = f"FIRMWARE_NAME:paced-echo\nCap:ADVANCED_OK:{int(advanced)}\nok"
                elif text.startswith("M114"):
                    reply = "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok"
                out = (reply + "\n").encode()
                wire_out = max(wire_in, wire_out) + len(out) * 10 / baud
                replies.append((wire_out, out))
        while replies and replies[0][0] - time.perf_counter() < 0.0003:
            _wait_until(replies[0][0])
            os.write(master, replies.pop(0)[1])
    q.put(lines)


def _pty_echo(master: int) -> None:
    while True:
        data = os.read(master, 256)
        if data == b"quit\n":
            os._exit(0)
        os.write(master, b"ok\n")


def pty_round_trip(n: int = 2000) -> float:
    """Median time for a line to cross a pty to another process and an ``ok`` to come
    back, with both ends blocked in ``read`` (no baud pacing), s."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    ctx = multiprocessing.get_context("fork")
    proc = ctx.Process(target=_pty_echo, args=(master,), daemon=True)
    proc.start()
    times = []
    line = frame(1, "G1 X103.484 Y97.431 E0.04211")
    for _ in range(n):
        t0 = time.perf_counter()
        os.write(slave, line)
        got = b""
        while not got.endswith(b"\n"):
            got += os.read(slave, 256)
        times.append(time.perf_counter() - t0)
    os.write(slave, b"quit\n")
    proc.join(5)
    os.close(slave)
    os.close(master)
    times.sort()
    return times[len(times) // 2]


def open_target(kind: str, profile: str, baud: int):
    """A printer in another process: ``(port, stop-and-return-executed-lines)``."""
    if kind == "simulator":
        tmp = tempfile.mkdtemp(prefix="bench_stream_")
        record = os.path.join(tmp, "record.json")
        proc, port = start_sim(profile, baud, record)

        def stop_sim() -> list[str]:
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=120)
            with open(record, encoding="utf-8") as fh:
                log = json.load(fh)["log"]
            shutil.rmtree(tmp, ignore_errors=True)
            return [t for _, t in log if not t.startswith(("M110", "M115", "M114", "M105"))]

        return port, stop_sim
    ctx = multiprocessing.get_context("fork")
    q, stop = ctx.Queue(), ctx.Event()
    proc = ctx.Process(target=_paced_responder,
                       args=(baud, profile == "marlin-advanced", q, stop), daemon=True)
    proc.start()
    port = q.get(timeout=20)

    def stop_responder() -> list[str]:
        stop.set()
        lines = q.get(timeout=20)
        proc.join(5)
        return lines

    return port, stop_responder


def run_printability(lines: list[str], kind: str, profile: str, mode: str, baud: int) -> dict:
    port, stop = open_target(kind, profile, baud)
    try:
        program = parse_program("\n".join(lines).encode(), source="bench.gcode")
        with Host(port, config=HostConfig(mode=mode, baud=baud)) as host:
            host.connect()
            t0 = time.perf_counter()
            report = host.stream(program)
            elapsed = time.perf_counter() - t0
    finally:
        got = stop()
    ok = got == lines
    return {"host": f"printability {report.mode}", "pingpong": report.mode == "ping-pong",
            "target": kind, "profile": profile, "seconds": elapsed, "lines": len(lines),
            "correct": ok}


def run_printcore(lines: list[str], kind: str, profile: str, baud: int) -> dict | None:
    try:
        from printrun import gcoder
        from printrun.printcore import printcore
    except ImportError as exc:
        print(f"printcore not available ({exc}); pip install --no-deps printrun",
              file=sys.stderr)
        return None
    port, stop = open_target(kind, profile, baud)
    core = printcore()
    got: list[str] = []
    try:
        online = threading.Event()
        core.onlinecb = online.set
        core.connect(port, baud)
        if not online.wait(20):
            raise RuntimeError("printcore did not come online")
        gc = gcoder.LightGCode(lines)
        t0 = time.perf_counter()
        core.startprint(gc)
        time.sleep(0.05)
        while core.printing:
            time.sleep(0.002)
        elapsed = time.perf_counter() - t0
        time.sleep(0.2)
    finally:
        core.disconnect()
        got = stop()
    ok = [c for c in got if c != "M105"] == lines
    return {"host": "printrun printcore", "pingpong": True, "target": kind, "profile": profile,
            "seconds": elapsed, "lines": len(lines), "correct": ok}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lines", type=int, default=10000)
    ap.add_argument("--baud", type=int, default=250000)
    ap.add_argument("--skip-printcore", action="store_true")
    args = ap.parse_args(argv)
    lines = make_gcode(args.lines)
    framed = sum(len(frame(i + 1, c)) for i, c in enumerate(lines)) / len(lines)
    line_rate = args.baud / 10 / framed
    print(f"{len(lines)} lines, {framed:.1f} bytes per framed line; wire line rate at "
          f"{args.baud} baud: {line_rate:.0f} lines/s")
    rtt = pty_round_trip()
    line_s = framed * 10 / args.baud
    ceiling = line_s / (line_s + 3 * 10 / args.baud + rtt)
    print(f"pty round trip on this machine: {rtt * 1e6:.0f} µs; ping-pong ceiling "
          f"(line + 'ok' on the wire + one pty round trip, ends that cost nothing): "
          f"{ceiling:.1%} of the line rate")
    rows = []
    for kind in ("simulator", "paced-echo"):
        rows.append(run_printability(lines, kind, "marlin", "ping-pong", args.baud))
        rows.append(run_printability(lines, kind, "marlin-advanced", "send-ahead", args.baud))
        if not args.skip_printcore:
            r = run_printcore(lines, kind, "marlin", args.baud)
            if r is not None:
                rows.append(r)
    print(f"{'host':26} {'printer':11} {'firmware':16} {'lines/s':>8} {'of wire':>8} "
          f"{'of ceiling':>10} {'vs ping-pong':>12} {'all once':>9}")
    base = {}
    for r in rows:
        rate = r["lines"] / r["seconds"]
        base.setdefault(r["target"], rate)
        print(f"{r['host']:26} {r['target']:11} {r['profile']:16} {rate:8.0f} "
              f"{rate / line_rate:8.1%} "
              f"{format(rate / line_rate / ceiling, '10.1%') if r['pingpong'] else '—':>10} "
              f"{rate / base[r['target']]:11.2f}× "
              f"{'yes' if r['correct'] else 'NO':>9}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
