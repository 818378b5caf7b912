"""Entry point of the ``printability`` command.

Each subcommand lives in its own module of this package and exposes
``register(app)``; this module only assembles them and turns library errors
into the exit-code contract of docs/design.md §4: 0 success, 1 a clear one-paragraph
error on stderr, 2 usage.
"""

from __future__ import annotations

import functools
import importlib
import sys
import textwrap
import warnings
from typing import TextIO

import typer
import typer.core

from printability import __version__
from printability.errors import PrintabilityError

__all__ = ["app", "main", "run"]

# Subcommand modules, in help order. Each defines register(app: typer.Typer).
SUBCOMMANDS: tuple[str, ...] = (
    "printability.app.cli.demo",
    "printability.app.cli.analyze",
    "printability.app.cli.postprocess",
    "printability.app.cli.generate",
    "printability.app.cli.simulate",
    "printability.app.cli.stream",
    "printability.app.cli.warmup",
    "printability.app.cli.serve",
)

#: One line per subcommand for ``printability --help`` (the command's docstring stays its
#: own ``--help``): click would cut a docstring's first sentence at about 45 columns.
SUMMARIES: dict[str, str] = {
    "demo": "The whole pipeline on a bundled part (start here).",
    "analyze": "What each nozzle prints of a part; nozzles ranked.",
    "postprocess": "Rewrite a slicer's G-code for a rotary-axis nozzle.",
    "generate": "Write G-code for a part from scratch (T-T-R).",
    "simulate": "Run the virtual printer on a pty or TCP port.",
    "stream": "Send G-code to a printer (or the simulator) over serial.",
    "warmup": "Compile the kernels once after installing.",
    "serve": "Keep a warm process for the slicer plug-in.",
}

_NO_BREAK_HYPHEN = "\u2011"


# click's classes as Typer uses them (Typer 0.28 carries its own copy of click)
_BaseContext = typer.core.TyperCommand.context_class


class HelpFormatter(_BaseContext.formatter_class):
    """click's help formatter, except that a line never breaks at a hyphen.

    Examples such as ``drop-ok@12`` or ``marlin-advanced`` stay whole (a reader copies
    them): hyphens become non-breaking while the text is wrapped, and plain again in the
    finished help.
    """

    def write_text(self, text: str) -> None:
        super().write_text(text.replace("-", _NO_BREAK_HYPHEN))

    def write_dl(self, rows, col_max: int = 30, col_spacing: int = 2) -> None:
        super().write_dl([(term, text.replace("-", _NO_BREAK_HYPHEN)) for term, text in rows],
                         col_max=col_max, col_spacing=col_spacing)

    def getvalue(self) -> str:
        return super().getvalue().replace(_NO_BREAK_HYPHEN, "-")


class _Context(_BaseContext):
    formatter_class = HelpFormatter


class _Command(typer.core.TyperCommand):
    context_class = _Context


class _Group(typer.core.TyperGroup):
    context_class = _Context


# Help is click's plain text, not rich's panels: rich squeezes option help into a column
# a third of an 80-column terminal wide and cuts SPECs such as ellipse:major=0.8,minor=0.3
# with "…"; click wraps help beside the options, whole, at any width.
app = typer.Typer(
    cls=_Group,
    name="printability",
    help="What of your part will this nozzle actually print, and how to print exactly that.",
    epilog="Start with 'printability demo': the whole pipeline on a bundled part against "
           "the built-in simulator, in about 10 s. 'printability COMMAND --help' describes "
           "a command. Lengths are in mm, angles in degrees.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"printability {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Show the version and exit."
    ),
) -> None:
    """printability: Maximum Material Condition analysis for any nozzle on any machine."""


for _name in SUBCOMMANDS:
    importlib.import_module(_name).register(app)
for _info in app.registered_commands:
    if _info.short_help is None and _info.name in SUMMARIES:
        _info.short_help = SUMMARIES[_info.name]
    if _info.cls in (None, typer.core.TyperCommand):
        _info.cls = _Command


#: Characters of an error message shown at most (a message quoting more input than that
#: would be long to wrap and to read; the places that quote input cut it shorter).
ERROR_LENGTH = 2000


def error_paragraph(exc: BaseException) -> str:
    """One paragraph, wrapped for a terminal; a message over :data:`ERROR_LENGTH`
    characters is cut and marked, so its cost does not depend on the input."""
    raw = str(exc)
    text = " ".join(raw[:4 * ERROR_LENGTH].split())
    if len(text) > ERROR_LENGTH or len(raw) > 4 * ERROR_LENGTH:
        text = text[:ERROR_LENGTH] + f" [… message cut at {ERROR_LENGTH} characters]"
    return textwrap.fill(f"printability: error: {text}", width=100)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code.

    ``postprocess`` is first offered to a running ``printability serve``
    (:func:`printability.app.server_client.run_remote`: the same file, messages and
    exit code, without the libraries' start), then run here by :func:`run`.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["postprocess"]:
        from printability.app.server_client import run_served

        rc = run_served(args)
        if rc is not None:
            return rc
    return run(args)


@functools.cache
def _command():
    """The click command Typer builds from ``app``, built once per process: Typer rebuilds
    it on every call (every subcommand's signature and type hints, about 20 ms), which
    each request to ``printability serve`` would pay. (Typer's own call adds only its
    pretty tracebacks, which ``app`` turns off.)"""
    return typer.main.get_command(app)


#: Subcommands that compile kernels on a first run.
_COMPILING = frozenset({"analyze", "postprocess", "generate", "demo", "serve"})


def run(argv: list[str] | None = None) -> int:
    """Run the CLI in this process; returns the process exit code.

    Typer (in standalone mode) prints usage errors itself and exits with 2;
    printability's own errors reach us as exceptions and become one paragraph
    on stderr with exit code 1. Anything else is a bug and keeps its traceback.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] and args[0] in _COMPILING and "--help" not in args:
        from printability.base.kernel_cache import announce_first_compile

        # the first run after an install or an upgrade: say why nothing happens, when the
        # first kernel actually compiles (not before a bad argument's one-paragraph error)
        announce_first_compile(lambda msg: print(msg, file=sys.stderr, flush=True))
    shown = warnings.showwarning
    warnings.showwarning = _show_warning
    try:
        _command()(args=argv, prog_name="printability", standalone_mode=True)
    except SystemExit as exc:
        code = exc.code
        ctrl_c = _keyboard_interrupt(exc)
        if ctrl_c is not None:  # Typer turns Ctrl-C into a silent exit 130: say it
            print(_interrupted(ctrl_c), file=sys.stderr)
        return code if isinstance(code, int) else (0 if code is None else 1)
    except PrintabilityError as exc:
        print(error_paragraph(exc), file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(_interrupted(exc), file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = shown
    return 0


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None) -> None:
    """A library's warning as one line of ours: no source path, no line of its code (a
    RuntimeWarning from numpy inside a reader printed both before our one-paragraph error)."""
    text = " ".join(str(message).split())
    if len(text) > 200:
        text = text[:200] + "…"
    print(f"printability: warning: {text}", file=sys.stderr if file is None else file)


def _keyboard_interrupt(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt ``exc`` was raised from, if any (its cause or context chain)."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, KeyboardInterrupt):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _interrupted(exc: KeyboardInterrupt) -> str:
    """One paragraph for Ctrl-C, with what the command said is left as it was (its notes)."""
    notes = "; ".join(getattr(exc, "__notes__", ()))
    return textwrap.fill("printability: interrupted" + (f"; {notes}" if notes else ""),
                         width=100)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
