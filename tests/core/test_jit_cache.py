"""The kernel caches are kept in step with every kernel module (printability._jit_cache)."""

from __future__ import annotations

import os
from pathlib import Path

from printability import _jit_cache

ROOT = Path(__file__).resolve().parents[2]


def test_the_list_of_kernel_modules_is_the_modules_with_cached_kernels():
    """A module that caches a kernel and is missing from the list would keep a stale callee."""
    found = sorted(
        str(p.relative_to(ROOT)) for pkg in ("printability", "gcode", "machine_io", "simulators",
                                             "plugin")
        for p in (ROOT / pkg).rglob("*.py") if "cache=True" in p.read_text(encoding="utf-8")
    )
    assert sorted(_jit_cache.KERNEL_MODULES) == found


def _tree(tmp_path: Path, *, sources: bool = True) -> Path:
    for rel in _jit_cache.KERNEL_MODULES:
        src = tmp_path / rel
        src.parent.mkdir(parents=True, exist_ok=True)
        if sources:
            src.write_text("x = 1\n")
        cache = src.parent / "__pycache__"
        cache.mkdir(exist_ok=True)
        (cache / f"{src.stem}.f-1.py311.nbi").write_bytes(b"index")
        (cache / f"{src.stem}.f-1.py311.1.nbc").write_bytes(b"code")
        (cache / f"{src.stem}.cpython-311.pyc").write_bytes(b"pyc")
    return tmp_path


def _caches(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.suffix in (".nbi", ".nbc"))


def test_caches_go_when_any_kernel_module_changes_and_stay_otherwise(tmp_path):
    root = _tree(tmp_path)
    assert _jit_cache.check(str(root))  # no stamp yet: unknown caches are not trusted
    assert _caches(root) == [] and list(root.rglob("*.pyc"))  # (only numba's)
    # caches written since, under the same sources, are kept
    _tree(root, sources=False)
    assert not _jit_cache.check(str(root))
    assert len(_caches(root)) == 2 * len(_jit_cache.KERNEL_MODULES)
    # one callee edited: every kernel cache goes, callers' included
    callee = root / "printability/motion/_covers.py"
    callee.write_text("x = 2  # a longer line\n")
    os.utime(callee, ns=(1, 1))
    assert _jit_cache.check(str(root))
    assert _caches(root) == []


def test_a_tree_it_cannot_write_is_left_alone(tmp_path):
    root = _tree(tmp_path)
    for d in root.rglob("__pycache__"):
        d.chmod(0o500)
    try:
        if os.access(next(root.rglob("__pycache__")), os.W_OK):  # running as root
            return
        _jit_cache.check(str(root))  # no exception
        assert len(_caches(root)) == 2 * len(_jit_cache.KERNEL_MODULES)
    finally:
        for d in root.rglob("__pycache__"):
            d.chmod(0o700)


def test_the_first_real_compile_is_announced_once_and_nothing_else_is():
    """The first-run notice comes when one of our kernels misses its cache and compiles, once
    per process; numba's own helpers (compiled on every run) say nothing."""
    import numba

    said: list[str] = []
    _jit_cache.announce_first_compile(said.append)

    def helper(x):
        return x + 1

    numba.njit(helper)(1)  # a test module's function: not ours
    assert said == []

    def ours(x):
        return x * 2

    ours.__module__ = "printability._probe"
    def ours2(x):
        return x * 3

    ours2.__module__ = "gcode._probe"
    numba.njit(ours)(2)
    numba.njit(ours2)(2)
    assert len(said) == 1 and "first run since installing" in said[0]


def test_a_bad_argument_on_a_cold_install_is_one_paragraph(tmp_path, shared_data):
    """On a fresh install (empty kernel caches) an argument error comes before any compile:
    the user sees only its paragraph (CI, on a clean checkout, found the notice printed first)."""
    import subprocess
    import sys

    src = shared_data / "slices" / "ACAM-Base--scaled_outline_mesh0_z4500.txt"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    p = subprocess.run([sys.executable, "-m", "printability", "analyze", str(src), "-n",
                        "hexagon:d=1"], capture_output=True, text=True, env=env, cwd=ROOT,
                       timeout=300)
    assert p.returncode == 1
    assert p.stderr.startswith("printability: error: unknown nozzle kind 'hexagon'"), p.stderr
