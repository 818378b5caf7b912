"""Post-processing entry point for PrusaSlicer, SuperSlicer and OrcaSlicer.

In *Print Settings → Output options → Post-processing scripts* put one line::

    printability-postprocess --nozzle ellipse:major=0.8,minor=0.3 --machine ttr

(on Windows the installed ``printability-postprocess.exe``: a console script,
so it runs where a bare ``.py`` would not). The slicer appends the path of
the G-code it just wrote as the **last argument**, exports its settings as
``SLIC3R_*`` environment variables and expects the file to be changed in
place; on failure it shows what the script printed on stderr. Options are
those of ``printability postprocess`` (``--help``); they can also be given in
the ``PRINTABILITY_POSTPROCESS_ARGS`` environment variable (shell syntax),
which is handy when the slicer's field is shared between printers.

PrusaSlicer ≥ 2.7 writes binary G-code (``.bgcode``) for printers that support
it and hands that binary file to its scripts: it is recognised by its content
and rewritten in place as binary G-code, thumbnails and metadata kept, the
G-code blocks re-encoded with the file's own compression and encoding (see
:mod:`gcode.bgcode`). A damaged binary file is a one-paragraph error and is
left untouched.

When ``printability serve`` is running, the run is handed to it (same output
file, same messages, same exit code) and this process costs Python's start and
a socket round trip instead of the libraries' start; otherwise, or if the
server declines or breaks off, it runs here (see
:mod:`printability.app.server_client`).
"""

from __future__ import annotations

import os
import sys

__all__ = ["build_argv", "main", "missing_file_message"]


def build_argv(argv: list[str], environ: dict[str, str] | None = None) -> list[str]:
    """The ``printability`` command line for a slicer's call: options first, the G-code last."""
    environ = dict(os.environ) if environ is None else environ
    extra: list[str] = []
    if environ.get("PRINTABILITY_POSTPROCESS_ARGS"):  # shlex only then: every export pays imports
        import shlex

        extra = shlex.split(environ["PRINTABILITY_POSTPROCESS_ARGS"])
    if not argv:
        return ["postprocess", "--help"]
    *options, gcode = argv
    if gcode.startswith("-"):  # no path: let the CLI explain its usage
        return ["postprocess", *extra, *argv]
    return ["postprocess", *extra, *options, gcode]


def missing_file_message(path: str) -> str:
    """The paragraph for a slicer's call whose last argument names no file."""
    return (f"printability: error: the slicer asked to post-process {path!r}, but there is no "
            "file there. A slicer appends the path of the G-code it just wrote (a temporary "
            "copy such as NAME.gcode.pp, or the plate's file in OrcaSlicer and Bambu Studio) "
            "as the last argument: check that the post-processing field ends with the options "
            "(nothing after them; OrcaSlicer and Bambu Studio also cut the field into separate "
            "commands at every ';'), and that no other script before this one moved or "
            "renamed the file.")


def main(argv: list[str] | None = None) -> int:
    """Run ``printability postprocess`` the way a slicer calls a script; returns the exit code."""
    args = build_argv(sys.argv[1:] if argv is None else argv)
    path = args[-1]
    if not path.startswith("-") and not os.path.exists(path):
        import textwrap

        print(textwrap.fill(missing_file_message(path), width=100, break_on_hyphens=False,
                            break_long_words=False), file=sys.stderr)
        return 1
    from printability.app.server_client import run_served

    rc = run_served(args)
    if rc is not None:
        return rc
    from printability.app.cli.main import run  # here, without asking the server again

    return run(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
