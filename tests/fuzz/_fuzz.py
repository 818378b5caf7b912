"""A seeded mutator of text inputs and a runner of the real CLI on each mutant.

The mutations are the ones that found bugs before (issue #24): flipped bytes, duplicated and
truncated lines, numbers replaced by ``nan``, ``inf``, ``1e309`` or hundreds of digits,
control characters, very long lines, and, for XML, duplicated elements and ``<use>`` of
existing ids. Every mutant is a function of (seed, index) alone, so a failure is replayed
with ``python tests/fuzz/_fuzz.py --replay SEED INDEX FILE``.

A run is *clean* (exit 0), an *error* (exit 1, stderr of ``printability:`` paragraphs ending
in the one-paragraph ``printability: error:``), or a failure: a *traceback*, a *hang* (no
exit within the timeout) or anything else (another exit code, a bare message).
"""

from __future__ import annotations

import argparse
import os
import random
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PYTHON = [sys.executable, "-m", "printability"]
NOZZLE = "ellipse:major=0.8,minor=0.3"

_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][+-]?\d+)?")
_ELEMENT = re.compile(rb"<(path|rect|circle|ellipse|polygon|g|use)\b[^<>]*/>")
_ID = re.compile(rb'\bid="([^"]+)"')
_WEIRD_NUMBERS = (b"nan", b"NaN", b"inf", b"-inf", b"1e309", b"-1e309", b"1e-320", b"-0",
                  b"9" * 400, b"0." + b"0" * 300 + b"1", b"1e15", b"1e16", b"0", b"-1",
                  b"99999999999999999999", b"1.5.5", b"", b"0x10", b"1_000")
_CONTROL = (b"\x00", b"\x01", b"\x07", b"\x1b", b"\x7f", b"\r", b"\x0b", b"\x0c", b"\xff",
            b"\xc3", b"\xe2\x80\xae")


def _flip(rng: random.Random, data: bytearray) -> None:
    for _ in range(rng.randint(1, 8)):
        if data:
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)


def _duplicate_lines(rng: random.Random, data: bytearray) -> None:
    lines = bytes(data).split(b"\n")
    i = rng.randrange(len(lines))
    n = rng.choice((1, 2, 10, 1000))
    lines[i:i + 1] = [lines[i]] * (n + 1)
    data[:] = b"\n".join(lines)


def _truncate(rng: random.Random, data: bytearray) -> None:
    del data[rng.randrange(len(data) + 1):]


def _drop_lines(rng: random.Random, data: bytearray) -> None:
    lines = bytes(data).split(b"\n")
    i = rng.randrange(len(lines))
    del lines[i:i + rng.randint(1, 50)]
    data[:] = b"\n".join(lines)


def _numbers(rng: random.Random, data: bytearray) -> None:
    spans = [m.span() for m in _NUMBER.finditer(data)]
    if not spans:
        return
    for a, b in sorted(rng.sample(spans, min(len(spans), rng.randint(1, 6))), reverse=True):
        data[a:b] = rng.choice(_WEIRD_NUMBERS)


def _control(rng: random.Random, data: bytearray) -> None:
    for _ in range(rng.randint(1, 4)):
        at = rng.randrange(len(data) + 1)
        data[at:at] = rng.choice(_CONTROL)


def _long_line(rng: random.Random, data: bytearray) -> None:
    at = rng.randrange(len(data) + 1)
    data[at:at] = rng.choice((b"X1 ", b"a", b"[1.5,2.5],", b"0")) * rng.choice((1000, 200_000))


def _xml_elements(rng: random.Random, data: bytearray) -> None:
    """Duplicate an element many times, or add <use> of an id (or of an unknown one)."""
    found = list(_ELEMENT.finditer(data))
    ids = _ID.findall(data) or [b"nothing"]
    at = rng.choice([m.end() for m in found]) if found else len(data) // 2
    if found and rng.random() < 0.5:
        piece = rng.choice(found).group(0) * rng.choice((2, 100, 5000))
    else:
        ref = rng.choice(ids)
        piece = b'<use xmlns:xlink="http://www.w3.org/1999/xlink" xlink:href="#%s"/>' % ref
        piece *= rng.choice((1, 10))
    data[at:at] = piece


GENERIC: tuple[Callable[[random.Random, bytearray], None], ...] = (
    _flip, _duplicate_lines, _truncate, _drop_lines, _numbers, _numbers, _control, _long_line)
# XML breaks at a flipped byte or a cut: fewer of those, more that keep it well-formed
XML = (_flip, _truncate, _control, _drop_lines, _duplicate_lines, _long_line, _numbers, _numbers,
       _numbers, _xml_elements, _xml_elements, _xml_elements)


def mutate(data: bytes, seed: int, index: int, *, xml: bool = False) -> bytes:
    """Mutant ``index`` of ``data`` for ``seed``: one to three mutations."""
    rng = random.Random(f"{seed}:{index}")
    out = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        rng.choice(XML if xml else GENERIC)(rng, out)
    return bytes(out)


def head_lines(path: Path, n: int = 2000) -> bytes:
    """The first ``n`` lines of a file."""
    with path.open("rb") as fh:
        return b"".join(line for _, line in zip(range(n), fh, strict=False))


@dataclass
class Outcome:
    kind: str  # clean, error, traceback, hang, other
    args: list[str]
    stderr: str = ""
    seconds: float = 0.0
    peak: int = 0  # the process's peak resident memory, bytes (0: not known)
    size: int = 0  # the input's size, bytes


@dataclass
class Tally:
    outcomes: list[Outcome] = field(default_factory=list)

    @property
    def counts(self) -> Counter:
        return Counter(o.kind for o in self.outcomes)

    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.kind not in ("clean", "error")]

    def line(self, name: str) -> str:
        c = self.counts
        peak = max((o.peak for o in self.outcomes), default=0)
        return (f"fuzz {name}: tried {len(self.outcomes)} / clean {c['clean']} / error "
                f"{c['error']} / traceback {c['traceback']} / hang {c['hang']} / other "
                f"{c['other']}; peak memory {peak / 2**20:.0f} MiB")

    def over_memory(self, reference: int, per_byte: float) -> list[Outcome]:
        """Runs whose peak memory passed the guard's estimate: ``per_byte`` times the input's
        size over ``reference`` (the peak of an unmutated run: the libraries and the sample),
        with a quarter of ``reference`` for the allocator's noise."""
        return [o for o in self.outcomes
                if o.peak > 1.25 * reference + per_byte * o.size]


def classify(returncode: int | None, stderr: str) -> str:
    """clean, error, traceback, hang or other (see the module docstring)."""
    if returncode is None:
        return "hang"
    if "Traceback" in stderr:
        return "traceback"
    if returncode == 0:
        return "clean"
    # warnings and notes may come first; the error is the last paragraph
    if (returncode == 1 and stderr.startswith("printability: ")
            and "printability: error:" in stderr):
        return "error"
    return "other"


def _input_size(args: Sequence[str]) -> int:
    """The size of the input file a command line names (its first existing path)."""
    nozzles = [Path(a.split(":", 1)[1]) for a in args if a.startswith("polygon:")]
    for path in [*nozzles, *map(Path, args[1:])]:  # the mutant is the nozzle, if one is
        if path.is_file():
            return path.stat().st_size
    return 0


def _high_water(pid: int) -> int | None:
    """The peak resident memory of process ``pid``'s address space so far (``VmHWM``), bytes;
    None once it has exited."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        pass
    return None


def run_cli(args: Sequence[str], *, timeout: float) -> Outcome:
    """Run ``printability ARGS``; its outcome, time and peak memory.

    The peak is the child's ``VmHWM`` read every 20 ms while it runs (the last reading: its
    address space's high-water mark). ``ru_maxrss`` would not do: it keeps the resident size
    of this process copied at the fork, before the exec.
    """
    t0 = time.monotonic()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PRINTABILITY_SERVER": "off"}
    proc = subprocess.Popen([*PYTHON, *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, cwd=ROOT, env=env)
    chunks: list[bytes] = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(
        lambda: proc.stderr.read(65536), b"")), daemon=True)
    reader.start()
    deadline = t0 + timeout
    status, peak = None, 0
    while True:
        hwm = _high_water(proc.pid)
        if hwm is not None:
            peak = hwm
        pid, wstatus, _ = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            status = os.waitstatus_to_exitcode(wstatus)
            proc.returncode = status  # reaped here: Popen must not wait for it again
            break
        if time.monotonic() > deadline:
            proc.kill()
            os.wait4(proc.pid, 0)
            proc.returncode = -9
            break
        time.sleep(0.02)
    reader.join(5)
    proc.stderr.close()
    err = b"".join(chunks).decode("utf-8", "replace")
    seconds = time.monotonic() - t0
    kind = "hang" if status is None else classify(status, err)
    return Outcome(kind, list(args), err[-2000:], seconds, peak, _input_size(args))


def gcode_jobs(samples: Sequence[Path], seed: int, count: int, folder: Path
               ) -> list[list[str]]:
    """``postprocess MUTANT -o OUT`` for ``count`` mutants of each sample's first 2000 lines."""
    jobs = []
    for sample in samples:
        data = head_lines(sample)
        for i in range(count):
            path = folder / f"{sample.stem}.{seed}.{i}.gcode"
            path.write_bytes(mutate(data, seed, i))
            jobs.append(["postprocess", str(path), "-o", str(path.with_suffix(".out.gcode")),
                         "--nozzle", NOZZLE])
    return jobs


def svg_jobs(samples: Sequence[Path], seed: int, count: int, folder: Path, part: Path
             ) -> list[list[str]]:
    """For ``count`` mutants of each SVG: ``analyze MUTANT``, and every other one as the
    nozzle of ``part`` (``--nozzle polygon:MUTANT``)."""
    jobs = []
    for sample in samples:
        data = sample.read_bytes()
        for i in range(count):
            path = folder / f"{sample.stem}.{seed}.{i}.svg"
            path.write_bytes(mutate(data, seed, i, xml=True))
            jobs.append(["analyze", str(path), "--no-progress", "-j", "1"])
            if i % 2 == 0:
                jobs.append(["analyze", str(part), "--nozzle", f"polygon:{path}",
                             "--no-progress", "-j", "1"])
    return jobs


def analyze_jobs(samples: Sequence[Path], seed: int, count: int, folder: Path,
                 extra: Sequence[str] = ()) -> list[list[str]]:
    """``analyze MUTANT EXTRA`` for ``count`` mutants of each sample (a map, slice outlines,
    a mesh, WKT: any input kind ``analyze`` reads)."""
    jobs = []
    for sample in samples:
        data = sample.read_bytes()
        for i in range(count):
            path = folder / f"{sample.stem}.{seed}.{i}{sample.suffix}"
            path.write_bytes(mutate(data, seed, i))
            jobs.append(["analyze", str(path), "--no-progress", "-j", "1", *extra])
    return jobs


def run_all(jobs: Sequence[Sequence[str]], *, timeout: float = 60.0, workers: int = 2
            ) -> Tally:
    with ThreadPoolExecutor(workers) as pool:
        return Tally(list(pool.map(lambda a: run_cli(a, timeout=timeout), jobs)))


def report(tally: Tally, name: str) -> str:
    lines = [tally.line(name)]
    for o in tally.failures():
        tail = o.stderr.strip().splitlines()[-3:] if o.stderr.strip() else ["(no stderr)"]
        lines.append(f"  {o.kind} after {o.seconds:.1f} s: printability {' '.join(o.args)}")
        lines.extend(f"    {t[:300]}" for t in tail)
    return "\n".join(lines)


def square_part(folder: Path) -> Path:
    """A 20 mm square drawing: the part a fuzzed nozzle polygon is tried on."""
    path = folder / "square20.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="20mm" height="20mm" '
                    'viewBox="0 0 20 20"><rect width="20" height="20"/></svg>')
    return path


def main(argv: Sequence[str] | None = None) -> int:  # pragma: no cover - a developer's tool
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--seed", type=int, default=24)
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--only", choices=("gcode", "svg"))
    ap.add_argument("--keep", type=Path, help="keep the mutants in this folder")
    args = ap.parse_args(argv)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="printability-fuzz-"))
    folder.mkdir(parents=True, exist_ok=True)
    bad = 0
    if args.only in (None, "gcode"):
        jobs = gcode_jobs(sorted((args.data / "gcode").glob("*.gcode")), args.seed, args.count,
                          folder)
        tally = run_all(jobs, timeout=args.timeout)
        print(report(tally, "gcode postprocess"), flush=True)
        bad += len(tally.failures())
    if args.only in (None, "svg"):
        jobs = svg_jobs(sorted((args.data / "svg").glob("*.svg")), args.seed, args.count,
                        folder, square_part(folder))
        tally = run_all(jobs, timeout=args.timeout)
        print(report(tally, "svg analyze / nozzle"), flush=True)
        bad += len(tally.failures())
    print(f"mutants in {folder}")
    return 1 if bad else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
