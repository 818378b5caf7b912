"""Stopping postprocess with any signal short of SIGKILL leaves the slicer's file as it was,
no temporary file beside it, and one paragraph on stderr."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

SAMPLE = "slic3rpe_1.33_arcwelder_benchy.gcode"  # a few seconds of work


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT])
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
    else:
        assert proc.returncode == 1
        assert f"stopped by {sig.name}" in err and "is unchanged" in err
        assert path.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name != "part.gcode"]


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
