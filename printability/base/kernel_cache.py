"""The compiled kernels' on-disk caches kept in step with their sources.

numba caches each compiled kernel beside its source (``__pycache__/*.nbi``, ``*.nbc``) and
checks only that one file's time and size before it loads it. A kernel that calls a kernel
of another module compiles the callee into itself, so when only the callee's file changes
(a ``git pull`` into an editable install), the caller's cache still holds the old callee:
seen here when the footprint scan's edge rows went from 8 to 4 columns in one file, and the
cached search in another went on reading 8 and accepting footprints it should have refused.

:func:`check`, run once per process before the first kernel is compiled or loaded from its
cache (:func:`guard`, called at the top of every module in :data:`KERNEL_MODULES`), stamps the
modules that hold kernels (:data:`KERNEL_MODULES`: name, time and size of each) and, when the
stamp differs from the one written beside their caches, removes those modules' caches: the
kernels are compiled again on their first calls (``printability warmup`` does it ahead).
Caches outside the source tree (numba's user-wide folder, used when the tree cannot be
written) belong to installs that pip rewrites whole, every file with a new time, so numba's
own check suffices there. Cost: one ``stat`` per kernel module (about 0.1 ms).
"""

from __future__ import annotations

import os
import threading

__all__ = ["KERNEL_MODULES", "announce_first_compile", "check", "ensure_checked", "guard"]

KERNEL_MODULES = (
    "gcode/_lexer.py",
    "gcode/_machine.py",
    "gcode/printtime.py",
    "gcode/text_kernels.py",
    "printability/generate/_emit_kernel.py",
    "printability/generate/_group_kernel.py",
    "printability/mmc/_band_geometry.py",
    "printability/mmc/_band_lists.py",
    "printability/mmc/_band_lower.py",
    "printability/mmc/_band_settle.py",
    "printability/mmc/_band_slides.py",
    "printability/mmc/_containment.py",
    "printability/mmc/_raster_kernels.py",
    "printability/mmc/_raster_runs.py",
    "printability/mmc/reference.py",
    "printability/planning/_bead_boundary.py",
    "printability/planning/_bead_polygons.py",
    "printability/planning/_boundary_grid.py",
    "printability/planning/_covers.py",
    "printability/planning/_first_fits.py",
    "printability/planning/_kernels.py",
    "printability/planning/_plan_kernels.py",
    "printability/planning/_point_location.py",
    "printability/planning/_sweep.py",
    "printability/planning/beadunion.py",
    "printability/planning/targets.py",
    "printability/planning/tiles.py",
    "printability/postprocess/_rewrite_kernel.py",
    "printability/postprocess/_rewrite_moves.py",
)
"""The modules with cached kernels, relative to the folder holding the packages (a test
checks the list against the sources)."""

_STAMP = os.path.join("printability", "__pycache__", "kernel-sources.stamp")


def _stamp(root: str) -> str:
    rows = []
    for rel in KERNEL_MODULES:
        try:
            st = os.stat(os.path.join(root, rel))
        except OSError:
            rows.append(f"{rel} missing")
            continue
        rows.append(f"{rel} {st.st_mtime_ns} {st.st_size}")
    return "\n".join(rows) + "\n"


def check(root: str | None = None) -> bool:
    """Remove the in-tree kernel caches when a kernel module changed since they were written;
    whether it removed any. ``root``: the folder holding the packages (default: this
    installation's). Never raises: a tree it cannot read or write is left as it is."""
    if root is None:
        # this file is <root>/printability/base/kernel_cache.py
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    stamp = _stamp(root)
    path = os.path.join(root, _STAMP)
    try:
        with open(path, encoding="utf-8") as f:
            if f.read() == stamp:
                return False
    except OSError:
        pass
    removed = False
    for folder in sorted({os.path.join(root, os.path.dirname(rel), "__pycache__")
                          for rel in KERNEL_MODULES}):
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            if name.endswith((".nbi", ".nbc")):
                try:
                    os.unlink(os.path.join(folder, name))
                    removed = True
                except OSError:
                    pass  # another process removed it first, or the tree is read-only
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(stamp)
        os.replace(tmp, path)
    except OSError:
        pass
    return removed


_lock = threading.Lock()
_checked = False
_guarded = False


def ensure_checked() -> None:
    """Run :func:`check` once in this process (later calls return at once)."""
    global _checked
    if _checked:
        return
    with _lock:
        if not _checked:
            check()
            _checked = True


def guard() -> None:
    """Arrange for :func:`ensure_checked` to run before this process's next numba compile.

    Called at the top of every module in :data:`KERNEL_MODULES`, so importing one writes and
    removes nothing (``import gcode.reader`` stays free of side effects); the check runs when
    numba first takes its compiler lock, which it holds around every compile *and* every load
    from the on-disk cache (``Dispatcher.compile``), so no kernel of ours can load a cache
    before the check. Uses numba's documented event ``numba:compiler_lock``; imports numba
    (the kernel modules import it anyway). Idempotent."""
    global _guarded
    if _guarded or _checked:
        return
    with _lock:
        if _guarded:
            return
        from numba.core import event

        class _BeforeFirstCompile(event.Listener):
            def on_start(self, ev) -> None:
                if not _checked:
                    ensure_checked()

            def on_end(self, ev) -> None:
                pass

        event.register("numba:compiler_lock", _BeforeFirstCompile())
        _guarded = True


def announce_first_compile(write) -> None:
    """Call ``write(message)`` once, when the first of this project's cached kernels is
    actually compiled in this process (a cache miss: the first run after an install or an
    upgrade), so that the minute it takes is not silent. Nothing happens on a warm run, or
    for a command that fails before it reaches a kernel (a bad argument gets its one-paragraph
    error and nothing else).

    Uses numba's event API: ``numba:compile`` fires only after the on-disk cache missed.
    Imports numba (the commands that call this compile kernels anyway)."""
    from numba.core import event

    class _Once(event.Listener):
        done = False

        def on_start(self, ev) -> None:
            if self.done:
                return
            disp = (ev.data or {}).get("dispatcher")
            module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
            if module.split(".")[0] not in ("printability", "gcode"):
                return  # numba's own helpers (typed containers) compile on every run
            self.done = True
            write("printability: first run since installing: compiling the kernels (about a "
                  "minute, once; 'printability warmup' does it ahead)")

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", _Once())
