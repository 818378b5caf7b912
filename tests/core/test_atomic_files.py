"""Every file written through a temporary file (reports, JSON, G-code, the simulator's record,
the host's resume file) is an ordinary file: 0666 less the umask when new, the mode and owner
of the file it replaces otherwise, and nothing left beside it when the write fails (issue #24:
they were all 0600, whatever the umask)."""

from __future__ import annotations

import json
import os

import pytest

import printability.base.files as files
from printability.base.files import current_umask, replace_file, write_atomic
from printability.errors import PrintabilityOSError


@pytest.fixture(params=["unnamed", "named"])
def how(request, monkeypatch):
    """Both ways a file is written: unnamed until complete (Linux's O_TMPFILE), and a named
    temporary file (elsewhere, or on a file system without O_TMPFILE)."""
    if request.param == "named":
        monkeypatch.setattr(files, "_unnamed", lambda directory: None)
    return request.param


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_a_new_file_gets_the_umask_mode(tmp_path, how, umask):
    old = os.umask(umask)
    try:
        assert current_umask() == umask
        write_atomic(tmp_path / "report" / "index.html", "<p>x</p>")
        replace_file(tmp_path / "record.json", b"{}")
    finally:
        os.umask(old)
    for p in (tmp_path / "report" / "index.html", tmp_path / "record.json"):
        assert p.stat().st_mode & 0o777 == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["record.json", "report"]


@pytest.mark.parametrize("mode", [0o644, 0o600, 0o664, 0o640])
def test_a_replaced_file_keeps_its_mode(tmp_path, how, mode):
    path = tmp_path / "part.gcode"
    path.write_bytes(b"old")
    path.chmod(mode)
    old = os.umask(0o077)
    try:
        replace_file(path, b"new")
    finally:
        os.umask(old)
    assert path.read_bytes() == b"new"
    assert path.stat().st_mode & 0o7777 == mode
    assert [p.name for p in tmp_path.iterdir()] == ["part.gcode"]


@pytest.mark.skipif(os.geteuid() != 0, reason="only root may give a file to another user")
def test_a_replaced_file_keeps_its_owner(tmp_path, how):
    path = tmp_path / "part.gcode"
    path.write_bytes(b"old")
    os.chown(path, 65534, 65534)
    replace_file(path, b"new")
    st = path.stat()
    assert (st.st_uid, st.st_gid) == (65534, 65534) and path.read_bytes() == b"new"


def test_a_failed_write_leaves_the_file_and_nothing_beside_it(tmp_path, how, monkeypatch):
    path = tmp_path / "part.gcode"
    path.write_bytes(b"old")

    def full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files.os, "fsync", full)
    with pytest.raises(PrintabilityOSError, match=r"part\.gcode: cannot write \(No space left"):
        write_atomic(path, b"new")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["part.gcode"]


def test_the_simulator_record_and_the_resume_file_are_ordinary_files(tmp_path):
    """Two writers of their own before (each made 0600 or set the mode by hand)."""
    from machine_io.reporting import _atomic_json
    from simulators.deposition import DepositionRecord, write_record

    old = os.umask(0o022)
    try:
        _atomic_json(tmp_path / "resume.json", {"next": 12})
        write_record(DepositionRecord(layers=(), log=()), tmp_path / "rec.json")
    finally:
        os.umask(old)
    for name in ("resume.json", "rec.json"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o644
        json.loads((tmp_path / name).read_text())
