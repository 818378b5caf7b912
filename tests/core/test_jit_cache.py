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


def test_cold_cache_is_seen(tmp_path):
    from printability._jit_cache import cold

    for rel in ("gcode/_lexer.py", "gcode/_machine.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    assert cold(str(tmp_path))  # a new install: nothing compiled yet
    cache = tmp_path / "gcode" / "__pycache__"
    cache.mkdir()
    (cache / "_lexer.lex_kernel-10.py311.nbi").write_bytes(b"")
    assert cold(str(tmp_path))
    (cache / "_machine._machine_impl-60.py311.nbi").write_bytes(b"")
    assert not cold(str(tmp_path))
