"""Benchmark: post-processing a part against the slicer's own time to slice it.

For each STL of ../shared/data/stl, the real PrusaSlicer (Debian's
``prusa-slicer``) slices it with ``tests/postprocess/data/prusaslicer_ttr.ini``;
then ``printability.postprocess`` rewrites that G-code for an elliptical
nozzle on a T-T-R machine (and, as the floor, for a round nozzle, which only
parses the file and adds the comment block). Printed per part: the slicer's
time, ours, their ratio (the goal: ≤ 1), and our throughput in lines/s next
to ArcWelder's published ~200 k lines/s (ArcWelder rewrites G1 runs into
arcs: a comparable "read every line, rewrite some" post-processor; its
figure is quoted, not measured here).

Both wall and CPU times are given: on a shared machine the wall time of one
process depends on the others, the CPU time much less. The slicer's CPU time
is that of its child process (``resource.getrusage(RUSAGE_CHILDREN)``). Both
tools use the machine's cores (we use one thread per core, at most 4: ``-j``), so
the CPU time is the sum over threads and the wall time what a user waits for.

Two figures for us: the work itself (``postprocess_bytes`` in this process,
after a warm-up: what the library costs per file), and the plugin as a slicer
runs it: a new ``printability-postprocess`` process per file (the console
script PrusaSlicer calls), whose time adds Python's and the libraries' start
(imports, numba's start and its cached kernels: "plugin start", timed on the
cube's first two layers). That second ratio is what a slicer's user waits for.
With ``printability serve`` running, the plug-in's process is timed as a user
installs it (from the project's wheel, in a virtual environment of its own) and
from this environment: an editable install starts every process with
setuptools' editable finder, which a user does not pay.

Run::

    python benchmarks/bench_postprocess.py            # every STL, 5 rounds (~15 min)
    python benchmarks/bench_postprocess.py --quick    # the calibration cube and ThinWall
    python benchmarks/bench_postprocess.py --repeat 1 # one round (noisier)

Each part is measured in rounds, each round running the slicer, the work and the
plugin (alone and served) in turn, so that they share the machine's drifts. Each
figure is the fastest of the rounds, the slicer's as ours; the paired ratios at
the end are the median over the rounds of our time over the slicer's in the same
round (on a noisy machine the two statistics bracket the truth).

Nothing here is asserted: the figures go in the README.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "stl"
CONFIG = ROOT / "tests" / "postprocess" / "data" / "prusaslicer_ttr.ini"
ARCWELDER_LINES_PER_S = 200_000
ELLIPSE = "ellipse:major=0.8,minor=0.3"


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def prusa_slicer() -> str | None:
    """The ``prusa-slicer`` executable, or None (after saying how to install it)."""
    exe = shutil.which("prusa-slicer")
    if exe is None:
        print("prusa-slicer is not installed (apt-get install prusa-slicer)", file=sys.stderr)
    return exe


def part_names(*, quick: bool) -> list[str]:
    """The STLs of ../shared/data/stl a run measures: all, or the two small ones."""
    if quick:
        return ["CalibrationCube.stl", "ThinWall.stl"]
    return sorted(p.name for p in DATA.glob("*.stl"))


def slice_part(exe: str, stl: Path, out: Path) -> tuple[float, float]:
    """Slice with PrusaSlicer; (wall s, CPU s)."""
    c0 = _children_cpu()
    t0 = time.perf_counter()
    subprocess.run([exe, "--export-gcode", "--load", str(CONFIG), "--center", "110,110",
                    "-o", str(out), str(stl)], check=True, capture_output=True)
    return time.perf_counter() - t0, _children_cpu() - c0


def postprocess(data: bytes, nozzle: str) -> tuple[float, float, object]:
    from printability.postprocess import PostprocessOptions, postprocess_bytes

    c0 = time.process_time()
    t0 = time.perf_counter()
    _, res = postprocess_bytes(data, options=PostprocessOptions(nozzle=nozzle, machine="ttr"))
    return time.perf_counter() - t0, time.process_time() - c0, res


def first_layers(data: bytes, n: int) -> bytes:
    """The G-code up to its (n+1)-th ``;LAYER_CHANGE`` (PrusaSlicer's layer marker)."""
    pos = -1
    for _ in range(n + 1):
        pos = data.find(b"\n;LAYER_CHANGE", pos + 1)
        if pos < 0:
            return data
    return data[:pos + 1]


def _process_cpu(pid: int | None) -> float:
    """CPU seconds of a running process (Linux /proc); 0 without one."""
    if pid is None:
        return 0.0
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def plugin_run(path: Path, nozzle: str, *, server: str = "off",
               server_pid: int | None = None, bindir: Path | None = None
               ) -> tuple[float, float]:
    """The plugin in a new process, as a slicer calls it (file rewritten in place), handing
    the run to the server at ``server`` if not "off"; (wall s, CPU s of the plugin process
    and of the server). ``bindir``: the environment whose ``printability-postprocess`` runs
    (default: this one)."""
    exe = (bindir or Path(sys.executable).parent) / "printability-postprocess"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "plugin.prusaslicer"]
    c0 = _children_cpu() + _process_cpu(server_pid)
    t0 = time.perf_counter()
    subprocess.run([*cmd, "--nozzle", nozzle, "--machine", "ttr", str(path)], check=True,
                   capture_output=True, cwd=ROOT, env={**os.environ, "PRINTABILITY_SERVER": server})
    return time.perf_counter() - t0, _children_cpu() + _process_cpu(server_pid) - c0


def user_install(tmp: Path) -> Path | None:
    """A virtual environment with printability installed from its wheel, as a user installs
    it (``pip install printability``), its dependencies taken from this environment; its
    ``bin`` directory, or None when the wheel cannot be built here (no build backend).

    A developer's editable install (``pip install -e``) starts every Python process with
    setuptools' editable finder (about 25 ms: it imports ``pathlib``, ``urllib`` and more),
    which a user's plug-in does not pay; the served plug-in is timed from both.
    """
    wheels, env = tmp / "wheel", tmp / "user-venv"
    try:
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                        str(wheels), str(ROOT)], check=True, capture_output=True)
        subprocess.run([sys.executable, "-m", "venv", str(env)], check=True,
                       capture_output=True)
        subprocess.run([str(env / "bin" / "python"), "-m", "pip", "install", "-q",
                        "--no-deps", "--no-index", *map(str, wheels.glob("*.whl"))],
                       check=True, capture_output=True)
    except (subprocess.CalledProcessError, OSError) as exc:
        print(f"no user install ({exc}): the served plug-in is timed from this environment "
              "only", file=sys.stderr)
        return None
    site = subprocess.run([str(env / "bin" / "python"), "-c",
                           "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    deps = subprocess.run([sys.executable, "-c",
                           "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    # a path line only: the .pth files of this environment (its editable finder) stay out
    Path(site, "zz_dependencies.pth").write_text(deps + "\n")
    return env / "bin"


def start_server(address: str) -> subprocess.Popen:
    """``printability serve`` at ``address``, returned once its kernels are loaded."""
    cli = Path(sys.executable).with_name("printability")
    proc = subprocess.Popen([str(cli), "serve", "--socket", address],
                            stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if "kernels loaded" in line:
            return proc
    raise RuntimeError("printability serve did not start")


def _fastest(runs) -> tuple[float, float]:
    """(wall s, CPU s) of repeated runs: the smallest of each (what the machine can do; the
    rest is other work sharing it)."""
    walls, cpus = zip(*runs, strict=True)
    return min(walls), min(cpus)


def _paired(ours: list[tuple[float, float]], slicer: list[tuple[float, float]]) -> float:
    """The median over the rounds of our CPU time over the slicer's in the same round: on a
    shared machine whose speed drifts, each round's two runs see about the same machine."""
    return statistics.median(o[1] / max(s[1], 1e-9) for o, s in zip(ours, slicer, strict=True))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="two small parts only")
    ap.add_argument("--repeat", type=int, default=5,
                    help="rounds of every measurement, the fastest kept (default 5): on a "
                         "shared machine one run of a small part varies by a third")
    args = ap.parse_args(argv)
    exe = prusa_slicer()
    if exe is None:
        return 1
    names = part_names(quick=args.quick)
    # warm up: imports and numba caches are paid once per process, not per file
    with tempfile.TemporaryDirectory() as tmp:
        os.chmod(tmp, 0o700)
        address = str(Path(tmp) / "serve.sock")
        server = start_server(address)
        try:
            return _run(exe, names, Path(tmp), args, address, server)
        finally:
            server.terminate()
            server.wait(30)


def _run(exe: str, names: list[str], tmp: Path, args, address: str,
         server: subprocess.Popen) -> int:
    warm = tmp / "warm.gcode"
    slice_part(exe, DATA / "CalibrationCube.stl", warm)
    head = warm.read_bytes()[:200_000]
    postprocess(head[:head.rfind(b"\n") + 1], ELLIPSE)  # whole lines: a cut one is refused
    # the plugin's start: a new process on the cube's first two layers (every kernel
    # loaded, almost no work)
    tiny = tmp / "two_layers.gcode"
    two = first_layers(warm.read_bytes(), 2)
    tiny.write_bytes(two)
    plugin_run(tiny, ELLIPSE)  # the first run may write caches
    rep = max(1, args.repeat)

    def start_once(**kw):
        tiny.write_bytes(two)
        return plugin_run(tiny, ELLIPSE, **kw)

    start_wall, start_cpu = _fastest(start_once() for _ in range(rep))
    dev = {"server": address, "server_pid": server.pid}
    user = user_install(tmp)
    served = {**dev, "bindir": user} if user is not None else dev
    sv_wall, sv_cpu = _fastest(start_once(**served) for _ in range(rep))
    dv_wall, dv_cpu = _fastest(start_once(**dev) for _ in range(rep))
    print(f"plugin start (the cube's first two layers): new process {start_wall:.2f} s wall, "
          f"{start_cpu:.2f} s CPU; served {sv_wall:.3f} s wall, {sv_cpu:.3f} s CPU "
          f"({'a user install' if user else 'this environment'}); served from this editable "
          f"install {dv_wall:.3f} s wall, {dv_cpu:.3f} s CPU")
    print(f"{'part':<24}{'lines':>8}{'slice s':>10}{'CPU':>7}"
          f"{'ellipse s':>11}{'CPU':>7}{'ratio':>7}{'wall r':>7}{'lines/s':>10}{'vs AW':>7}"
          f"{'round s':>9}{'lines/s':>10}{'split':>7}{'dropped':>8}"
          f"{'plugin s':>10}{'CPU':>7}{'ratio':>7}{'wall r':>7}"
          f"{'served s':>10}{'CPU':>7}{'ratio':>7}{'wall r':>7}")
    paired = []
    for name in names:
        out = tmp / (Path(name).stem + ".gcode")
        slice_part(exe, DATA / name, out)
        data = out.read_bytes()
        res = postprocess(data, ELLIPSE)[2]

        def plugin_once(out=out, data=data, **kw):
            out.write_bytes(data)  # the plugin rewrites it in place
            return plugin_run(out, ELLIPSE, **kw)

        # rounds of every measurement in turn, so that the slicer and we share the
        # machine's drifts (the slicer's output is the same file every time)
        rounds = {"slice": [], "work": [], "round": [], "plugin": [], "served": [],
                  "dev": []}
        for _ in range(rep):
            rounds["slice"].append(slice_part(exe, DATA / name, out))
            rounds["work"].append(postprocess(data, ELLIPSE)[:2])
            rounds["round"].append(postprocess(data, "circle:d=0.4")[:2])
            rounds["plugin"].append(plugin_once())
            rounds["served"].append(plugin_once(**served))
            rounds["dev"].append(plugin_once(**dev))
        s_wall, s_cpu = _fastest(rounds["slice"])
        e_wall, e_cpu = _fastest(rounds["work"])
        r_wall, r_cpu = _fastest(rounds["round"])
        p_wall, p_cpu = _fastest(rounds["plugin"])
        v_wall, v_cpu = _fastest(rounds["served"])
        paired.append((name, _paired(rounds["work"], rounds["slice"]),
                       _paired(rounds["served"], rounds["slice"]),
                       _paired(rounds["dev"], rounds["slice"])))
        if server.poll() is not None:
            print("the server stopped (its source files changed?): the served figures are "
                  "local runs", file=sys.stderr)
            return 1
        lines = res.lines_in
        print(f"{name[:23]:<24}{lines:>8}{s_wall:>10.2f}{s_cpu:>7.2f}"
              f"{e_wall:>11.2f}{e_cpu:>7.2f}{e_cpu / max(s_cpu, 1e-9):>7.2f}"
              f"{e_wall / max(s_wall, 1e-9):>7.2f}"
              f"{lines / max(e_cpu, 1e-9):>10.0f}"
              f"{lines / max(e_cpu, 1e-9) / ARCWELDER_LINES_PER_S:>7.2f}"
              f"{r_wall:>9.2f}{lines / max(r_cpu, 1e-9):>10.0f}"
              f"{res.split_moves:>7}{res.dropped_moves:>8}"
              f"{p_wall:>10.2f}{p_cpu:>7.2f}{p_cpu / max(s_cpu, 1e-9):>7.2f}"
              f"{p_wall / max(s_wall, 1e-9):>7.2f}"
              f"{v_wall:>10.2f}{v_cpu:>7.2f}{v_cpu / max(s_cpu, 1e-9):>7.2f}"
              f"{v_wall / max(s_wall, 1e-9):>7.2f}")
    print("ratio = our CPU time / the slicer's CPU time for the same part (goal <= 1); "
          "wall r = the same for wall-clock times (both use threads); "
          f"vs AW = our lines/s (CPU) / ArcWelder's ~{ARCWELDER_LINES_PER_S:,} lines/s; "
          "plugin = a new printability-postprocess process per file, as the slicer runs it; "
          "served = the same with `printability serve` running (plugin + server CPU; the "
          "plugin from a user install when one could be built, else this one)")
    print(f"paired ratios (median over the {rep} rounds of our CPU / the slicer's in the same "
          "round):")
    for name, work, served_r, dev_r in paired:
        print(f"  {name[:23]:<24} the work {work:.2f}   served {served_r:.2f}   "
              f"served from the editable install {dev_r:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
