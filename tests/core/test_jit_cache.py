"""The kernel caches are kept in step with every kernel module (printability.base.kernel_cache)."""

from __future__ import annotations

import os
from pathlib import Path

from printability.base import kernel_cache

ROOT = Path(__file__).resolve().parents[2]


def test_the_list_of_kernel_modules_is_the_modules_with_cached_kernels():
    """A module that caches a kernel and is missing from the list would keep a stale callee."""
    found = sorted(
        str(p.relative_to(ROOT)) for pkg in ("printability", "gcode", "machine_io", "simulators",
                                             "plugin")
        for p in (ROOT / pkg).rglob("*.py") if "cache=True" in p.read_text(encoding="utf-8")
    )
    assert sorted(kernel_cache.KERNEL_MODULES) == found


def _tree(tmp_path: Path, *, sources: bool = True) -> Path:
    for rel in kernel_cache.KERNEL_MODULES:
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
    assert kernel_cache.check(str(root))  # no stamp yet: unknown caches are not trusted
    assert _caches(root) == [] and list(root.rglob("*.pyc"))  # (only numba's)
    # caches written since, under the same sources, are kept
    _tree(root, sources=False)
    assert not kernel_cache.check(str(root))
    assert len(_caches(root)) == 2 * len(kernel_cache.KERNEL_MODULES)
    # one callee edited: every kernel cache goes, callers' included
    callee = root / "printability/planning/_covers.py"
    callee.write_text("x = 2  # a longer line\n")
    os.utime(callee, ns=(1, 1))
    assert kernel_cache.check(str(root))
    assert _caches(root) == []


def test_a_tree_it_cannot_write_is_left_alone(tmp_path):
    root = _tree(tmp_path)
    for d in root.rglob("__pycache__"):
        d.chmod(0o500)
    try:
        if os.access(next(root.rglob("__pycache__")), os.W_OK):  # running as root
            return
        kernel_cache.check(str(root))  # no exception
        assert len(_caches(root)) == 2 * len(kernel_cache.KERNEL_MODULES)
    finally:
        for d in root.rglob("__pycache__"):
            d.chmod(0o700)


def test_the_first_real_compile_is_announced_once_and_nothing_else_is():
    """The first-run notice comes when one of our kernels misses its cache and compiles, once
    per process; numba's own helpers (compiled on every run) say nothing."""
    import numba

    said: list[str] = []
    kernel_cache.announce_first_compile(said.append)

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


def test_every_kernel_module_arms_the_check_before_its_kernels():
    """The check runs before the first compile or cache load (not when the package is
    imported): each kernel module calls the guard, above its first cached kernel."""
    for rel in kernel_cache.KERNEL_MODULES:
        text = (ROOT / rel).read_text(encoding="utf-8")
        call = text.find("\n_guard_kernel_caches()")
        assert call != -1, f"{rel}: call printability.base.kernel_cache.guard() at the top"
        assert call < text.find("cache=True"), f"{rel}: the guard comes after a kernel"


_ORDER_PROBE = r"""
import sys
import numba.core.caching as caching
import printability.base.kernel_cache as k

order = []
k.check = lambda root=None: order.append("check")  # the real one may remove caches


class Stop(Exception):
    pass


def load(self, sig, target_context):
    order.append("load")
    raise Stop  # no compile: only the order matters


caching.Cache.load_overload = load
import printability, printability.base.errors  # noqa: E401
assert "printability.base.kernel_cache" in sys.modules  # (this probe imported it)
import gcode.reader

print("after-import", order, k._checked)
try:
    gcode.reader.parse_gcode(b"G1 X1 Y1\n")
except Stop:
    pass
print("after-call", order[:2])
"""


def test_importing_the_reader_runs_no_check_and_the_check_precedes_the_first_load():
    """``import gcode.reader`` (which imports kernel modules) writes nothing and runs no
    check; its first kernel call runs the check before numba loads any cache. A fresh process,
    so that nothing else has run the check first."""
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-c", _ORDER_PROBE], capture_output=True, text=True,
                       cwd=ROOT, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines == ["after-import [] False", "after-call ['check', 'load']"], \
        p.stdout + p.stderr


def test_importing_the_package_or_its_base_loads_no_kernel_machinery():
    import subprocess
    import sys

    code = ("import sys, printability, printability.base.errors, printability.base.options, "
            "printability.base.settings, printability.errors;"
            "print(sorted(m for m in sys.modules if 'kernel_cache' in m or 'jit_cache' in m "
            "or m.split('.')[0] == 'numba'))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[]"
