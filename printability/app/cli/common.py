"""Helpers shared by the subcommand adapters: option help from the registries,
atomic writes, progress bars."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any

from printability.base.files import write_atomic
from printability.errors import StoppedError
from printability.options import Registry

__all__ = ["MACHINE_SPEC_HELP", "NOZZLE_SPEC_HELP", "choices_help", "note_default_layer_height",
           "progress_callback", "spec_epilog", "stage_progress", "stop_signals_raise",
           "write_atomic",
           "write_json_atomic"]

# The full SPEC syntax, printed once below a command's options (click keeps a paragraph that
# starts with \b as written): an option's own help stays one or two short lines, and no
# example is folded into a narrow column at 80 columns.
NOZZLE_SPEC_HELP = """Nozzle SPEC (--nozzle):

\b
  circle:d=0.4                         round orifice, 0.4 mm across
  ellipse:major=0.8,minor=0.3          elliptical orifice, its two axes
  rect:w=0.8,h=0.3                     rectangular orifice
  polygon:FILE.svg                     any outline, read from a drawing
  polygon:pts=0 0;1 0;1 0.3            any outline, from its vertices
  ellipse:major=0.8,minor=0.3,angle=30 mounted turned by 30°
  rect:w=0.8,h=0.3,x=1,y=0             1 mm off the rotation axis
  circle:d=0.4,x=-1+circle:d=0.4,x=1   two orifices on one head"""
"""Nozzle SPEC syntax for a command's epilog (see :func:`spec_epilog`)."""

MACHINE_SPEC_HELP = """Machine SPEC (--machine):

\b
  xy                                   X and Y only: the nozzle never turns
  ttr                                  X, Y and a rotary axis turning it
  ttr:min=-90,max=90,step=1            a rotary axis limited to ±90°,
                                       sampled every 1°
  ttr-klipper, polar, scara            built-in profiles
  my_printer.toml                      a machine file, as documented in
                                       printability/data/machines/ttr.toml

Lengths are in mm, angles in degrees."""
"""Machine SPEC syntax for a command's epilog (see :func:`spec_epilog`)."""


def spec_epilog(*, nozzle: bool = True, machine: bool = True) -> str:
    """The SPEC syntax a command's ``--help`` ends with.

    Parameters
    ----------
    nozzle, machine
        Include the nozzle / machine SPEC syntax.

    Returns
    -------
    str
        Paragraphs for click's ``epilog``: each table is kept as written, 80 columns wide.
    """
    return "\n\n".join(t for t, on in ((NOZZLE_SPEC_HELP, nozzle), (MACHINE_SPEC_HELP, machine))
                       if on)


def choices_help(registry: Registry, text: str) -> str:
    """Help text that lists a registry's choices (the CLI reads the same registry)."""
    return f"{text} One of: {', '.join(registry.choices)}."


def write_json_atomic(path: str | Path, doc: Any) -> None:
    write_atomic(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


@contextlib.contextmanager
def progress_callback(description: str, *, enabled: bool) -> Iterator[Callable[[int, int], None]]:
    """A rich progress bar on stderr, exposed as an ``on_progress(done, total)`` callback."""
    if not enabled or (not sys.stderr.isatty() and not os.environ.get("PRINTABILITY_PROGRESS")):
        yield lambda done, total: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


@contextlib.contextmanager
def stage_progress(*, enabled: bool) -> Iterator[Callable[[str, int, int], None]]:
    """A one-line rich display on stderr, exposed as an ``on_progress(stage, done, total)``
    callback: the stage's name, a bar (a moving one while ``total`` is 0: a stage with no
    count), ``done/total`` and the time spent. Shown in a terminal (or with
    ``PRINTABILITY_PROGRESS`` set), gone when the block ends."""
    if not enabled or (not sys.stderr.isatty() and not os.environ.get("PRINTABILITY_PROGRESS")):
        yield lambda stage, done, total: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    def count(done: int, total: int) -> str:
        return f"{done:,}/{total:,}" if total else ""  # a stage with no count shows none

    with Progress("[progress.description]{task.description}", BarColumn(),
                  TextColumn("{task.fields[count]}"), TimeElapsedColumn(),
                  console=Console(stderr=True), transient=True) as bar:
        current = {"stage": "starting",
                   "task": bar.add_task("starting", total=None, count="")}

        def update(stage: str, done: int, total: int) -> None:
            if stage != current["stage"]:  # a task per stage: its own count and clock
                bar.remove_task(current["task"])
                current.update(stage=stage, task=bar.add_task(stage, total=total or None,
                                                              completed=done,
                                                              count=count(done, total)))
                bar.refresh()  # a stage may take long: show it now, not at the next tick
            else:
                bar.update(current["task"], completed=done, total=total or None,
                           count=count(done, total))

        yield update


#: Packages whose Python code must not be unwound half-way by an exception from a signal
#: handler: numba's compiler and cache loader, and llvmlite's callbacks from LLVM (an exception
#: there is "ignored" by ctypes, printed as a traceback, and can leave LLVM with a half-built
#: object: a segmentation fault a moment later).
_UNINTERRUPTIBLE = frozenset({"numba", "llvmlite"})
_RETRY_SECONDS = 0.02


def _in_uninterruptible(frame: FrameType | None) -> bool:
    """Whether ``frame`` or one of its callers is code of :data:`_UNINTERRUPTIBLE`."""
    while frame is not None:
        name = frame.f_globals.get("__name__")
        if isinstance(name, str) and name.partition(".")[0] in _UNINTERRUPTIBLE:
            return True
        frame = frame.f_back
    return False


@contextlib.contextmanager
def stop_signals_raise(what: str) -> Iterator[None]:
    """Within the block, SIGTERM, SIGHUP and SIGQUIT raise :class:`StoppedError`, and Ctrl-C
    raises KeyboardInterrupt with ``what`` as a note (the CLI prints it after
    "interrupted").

    Their default action ends the process at once, leaving a half-written temporary file
    beside the user's; raised as an exception, the atomic write's cleanup runs and the user
    reads one paragraph (``what`` says what is left as it was). A signal that comes while
    numba compiles or loads a kernel (llvmlite's callbacks from LLVM among it) is delivered
    again every 20 ms until that code is left: an exception there crashed the process. A
    signal the process ignores (``nohup``, a background job's Ctrl-C) stays ignored. Only in
    the main thread (signal handlers can be set nowhere else). A handler set before
    (``printability serve``'s: the signal stops the server, not only this run) runs first,
    and what it raises stops the block instead.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    old: dict = {}
    main = threading.main_thread().ident

    def stop(signum: int, frame: FrameType | None) -> None:
        if _in_uninterruptible(frame):
            retry = threading.Timer(_RETRY_SECONDS, signal.pthread_kill, (main, signum))
            retry.daemon = True
            retry.start()
            return
        before = old.get(signum)
        if callable(before) and before is not signal.default_int_handler:
            before(signum, frame)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise StoppedError(f"stopped by {signal.Signals(signum).name}; {what}")

    names = ("SIGTERM", "SIGHUP", "SIGQUIT", "SIGINT")
    for sig in (getattr(signal, n) for n in names if hasattr(signal, n)):
        if signal.getsignal(sig) is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, stop)
    try:
        yield
    except KeyboardInterrupt as exc:  # Ctrl-C: the CLI says "interrupted" and what is kept
        exc.add_note(what)
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)


_MESHES = (".stl", ".3mf", ".obj")


def note_default_layer_height(path: object, layer_height: float | None) -> None:
    """Say on stderr when a mesh is sliced at the default layer height the user did not give."""
    if layer_height is None and str(path).lower().endswith(_MESHES):
        from printability.sources.mesh import DEFAULT_LAYER_HEIGHT

        print(f"printability: {path}: slicing at {DEFAULT_LAYER_HEIGHT:g} mm layers "
              "(give --layer-height to choose)", file=sys.stderr)
