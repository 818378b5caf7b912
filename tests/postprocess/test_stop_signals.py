"""Stopping postprocess with any signal short of SIGKILL leaves the slicer's file as it was,
no temporary file beside it, and one paragraph on stderr."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

SAMPLE = "slic3rpe_1.33_arcwelder_benchy.gcode"  # a few seconds of work


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGINT])
def test_stop_signal_leaves_the_file(shared_data, tmp_path, sig):
    path = tmp_path / "part.gcode"
    path.write_bytes((shared_data / "gcode" / SAMPLE).read_bytes())
    before = path.read_bytes()
    proc = subprocess.Popen([sys.executable, "-m", "printability", "postprocess", str(path),
                             "--nozzle", "ellipse:major=0.8,minor=0.3", "--machine", "ttr"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # past the imports, into the work (the numba kernels come from the cache)
    time.sleep(2.0)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=600)
    err = " ".join(err.split())  # the paragraph is wrapped to the terminal
    assert "Traceback" not in err
    print(sig.name, proc.returncode, err[:200])
    if proc.returncode == 0:  # it finished first: the whole file, processed
        assert path.read_bytes() != before
    elif proc.returncode == -sig:
        # a loaded machine: the signal came during the imports, before the command set its
        # handlers and before it opened anything; the default action ended it
        assert path.read_bytes() == before
    elif sig == signal.SIGINT:  # Ctrl-C: KeyboardInterrupt, the CLI's "interrupted"
        assert proc.returncode == 130 and "interrupted" in err
        assert path.read_bytes() == before
    else:
        assert proc.returncode == 1
        assert f"stopped by {sig.name}" in err and "is unchanged" in err
        assert path.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name != "part.gcode"]


# The signal sent from inside the write: the new content is in the file that will replace the
# slicer's, which is not renamed yet (os.fsync is the last step before the rename). The real
# CLI in its own process, the signal at the worst moment instead of at a guessed time.
_KILL_IN_WRITE = """
import os, sys
sig = int(sys.argv[1])
real_fsync = os.fsync
def fsync(fd):
    os.kill(os.getpid(), sig)
    real_fsync(fd)
os.fsync = fsync
from printability.app.cli.main import run
sys.exit(run(sys.argv[2:]))
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGINT,
                                 signal.SIGKILL], ids=lambda s: signal.Signals(s).name)
def test_a_signal_during_the_write_leaves_the_file_and_no_temporary(prusa_short, tmp_path, sig):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    before = path.read_bytes()
    r = subprocess.run([sys.executable, "-c", _KILL_IN_WRITE, str(int(sig)), "postprocess",
                        str(path), "--nozzle", "ellipse:major=0.8,minor=0.3"],
                       capture_output=True, text=True, timeout=600)
    err = " ".join(r.stderr.split())
    assert "Traceback" not in err, err
    expected = {signal.SIGKILL: -signal.SIGKILL, signal.SIGINT: 130}.get(sig, 1)
    assert r.returncode == expected, err
    if sig not in (signal.SIGKILL, signal.SIGINT):
        assert f"stopped by {sig.name}" in err and "is unchanged" in err, err
    assert path.read_bytes() == before
    # SIGKILL runs no cleanup: the new content was written to a file with no name yet
    assert [p.name for p in tmp_path.iterdir()] == ["part.gcode"]


@pytest.mark.parametrize(("mode", "umask"), [(0o640, 0o022), (0o664, 0o077), (0o600, 0o000)])
def test_an_in_place_rewrite_keeps_the_files_mode(prusa_short, tmp_path, mode, umask):
    from printability.postprocess import PostprocessOptions, postprocess_file

    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    path.chmod(mode)
    old = os.umask(umask)
    try:
        postprocess_file(path, options=PostprocessOptions(nozzle="ellipse:major=0.8,minor=0.3"))
    finally:
        os.umask(old)
    assert b"; printability " in path.read_bytes()  # it was rewritten
    assert path.stat().st_mode & 0o7777 == mode


@pytest.mark.skipif(os.geteuid() != 0, reason="only root may give a file to another user")
def test_an_in_place_rewrite_by_root_keeps_the_files_owner(prusa_short, tmp_path):
    """A slicer's file post-processed by root (a print server running as root, sudo) stays
    the user's: before, the rename left a root-owned file the user could no longer rewrite."""
    from printability.postprocess import PostprocessOptions, postprocess_file

    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    os.chown(path, 65534, 65534)
    postprocess_file(path, options=PostprocessOptions(nozzle="ellipse:major=0.8,minor=0.3"))
    st = path.stat()
    assert b"; printability " in path.read_bytes()
    assert (st.st_uid, st.st_gid) == (65534, 65534)


def test_devices_and_fifos_are_refused(tmp_path):
    fifo = tmp_path / "fifo.gcode"
    os.mkfifo(fifo)
    for p in ("/dev/zero", str(fifo)):
        r = subprocess.run([sys.executable, "-m", "printability", "postprocess", p, "--nozzle",
                            "ellipse:major=0.8,minor=0.3"], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 1 and "not a regular file" in " ".join(r.stderr.split())


def test_a_new_output_file_gets_the_umask_mode(prusa_short, tmp_path):
    out = tmp_path / "out.gcode"
    old = os.umask(0o027)
    try:
        from printability.postprocess import PostprocessOptions, postprocess_file

        postprocess_file(prusa_short, output=out,
                         options=PostprocessOptions(nozzle="ellipse:major=0.8,minor=0.3"))
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o640  # as open() would make it, not mkstemp's 0600


@pytest.mark.parametrize("name", ["../../x.gcode", "a\nb.gcode", "dir/x.gcode", ""])
def test_output_name_must_be_a_file_name(prusa_short, tmp_path, name):
    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    before = path.read_bytes()
    r = subprocess.run([sys.executable, "-m", "printability", "postprocess", "--nozzle",
                        "ellipse:major=0.8,minor=0.3", "--output-name", name, str(path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "output name expects a file name" in " ".join(r.stderr.split())
    assert path.read_bytes() == before
    assert not (tmp_path / "part.gcode.output_name").exists()


_INSIDE_NUMBA = """
def compile_step(signum):
    os.kill(os.getpid(), signum)  # the signal comes while numba's code runs
    t = time.monotonic()
    while time.monotonic() - t < 0.2:
        pass
    return "finished"
"""


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(),
                    reason="signal handlers are set in the main thread only")
@pytest.mark.parametrize(("sig", "raised"), [(signal.SIGTERM, "StoppedError"),
                                             (signal.SIGINT, "KeyboardInterrupt")])
def test_a_stop_inside_numba_waits_until_numba_is_left(sig, raised):
    """An exception raised from the handler inside numba's compiler or llvmlite's callbacks
    from LLVM ("Exception ignored on calling ctypes callback function", then a segmentation
    fault): the signal is delivered again once that code is left."""
    from printability.app.cli.common import stop_signals_raise
    from printability.errors import StoppedError

    ns = {"__name__": "numba.core.probe", "os": os, "time": time}
    exec(_INSIDE_NUMBA, ns)  # a function whose globals say it is numba's
    finished = []
    expected = {"StoppedError": StoppedError, "KeyboardInterrupt": KeyboardInterrupt}[raised]
    with pytest.raises(expected) as info:
        with stop_signals_raise("part.gcode is unchanged"):
            finished.append(ns["compile_step"](sig))
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:  # the signal is delivered again here
                time.sleep(0.005)
    assert finished == ["finished"]
    if sig == signal.SIGINT:
        assert info.value.__notes__ == ["part.gcode is unchanged"]
    else:
        assert str(info.value) == "stopped by SIGTERM; part.gcode is unchanged"


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(),
                    reason="signal handlers are set in the main thread only")
def test_an_ignored_hangup_stays_ignored():
    """Under nohup SIGHUP is ignored: closing the terminal must not stop the run."""
    from printability.app.cli.common import stop_signals_raise

    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with stop_signals_raise("part.gcode is unchanged"):
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)


@pytest.mark.parametrize(("nozzle", "refused"), [
    ("circle:d=0.4", False),  # lays the slicer's beads: nothing planned
    ("ellipse:major=0.8,minor=0.3", True),  # refused before the file is read
    ("circle:d=1.2", True),  # wider than the slicer's beads: refused once the file says so
])
def test_the_memory_guard_knows_a_planned_run_needs_more(prusa_short, tmp_path, monkeypatch,
                                                         nozzle, refused):
    """A run that plans every move holds about 90 bytes per byte of G-code (the plan, the
    output read again for its print time), one that keeps the slicer's moves about 23: the
    guard that said 25 for both would have let a 200 MB file with an elliptical nozzle grow
    to about 18 GB (1.5 GB measured for 15 MB). Here the limit lies between the two
    estimates."""
    import printability.postprocess as pp
    from printability.errors import ResourceError
    from printability.postprocess import memory
    from printability.settings import Settings

    path = tmp_path / "part.gcode"
    path.write_bytes(prusa_short.read_bytes())
    size = path.stat().st_size
    limit = (memory.BYTES_PER_BYTE_KEPT + memory.BYTES_PER_BYTE_PLANNED) * size // 2
    monkeypatch.setattr(memory, "DEFAULT_SETTINGS", Settings(max_memory=limit))
    before = path.read_bytes()
    opts = pp.PostprocessOptions(nozzle=nozzle)
    if refused:
        with pytest.raises(ResourceError, match=r"part\.gcode: .* with this nozzle \(every "
                                                r"move planned\), more than the limit"):
            pp.postprocess_file(path, options=opts)
        assert path.read_bytes() == before
    else:
        pp.postprocess_file(path, options=opts)
        assert b"; printability " in path.read_bytes()
    # and below the least estimate, nothing is read
    monkeypatch.setattr(memory, "DEFAULT_SETTINGS", Settings(max_memory=size))
    monkeypatch.setattr(Path, "read_bytes", lambda self: pytest.fail("the file was read"))
    with pytest.raises(ResourceError, match="MiB of G-code would need about"):
        pp.postprocess_file(tmp_path / "part.gcode", options=opts)
