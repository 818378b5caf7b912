"""Entry point of the ``printability`` command.

Each subcommand lives in its own module of this package and exposes
``register(app)``; this module only assembles them and turns library errors
into the exit-code contract of DESIGN.md §4: 0 success, 1 a clear one-paragraph
error on stderr, 2 usage.
"""

from __future__ import annotations

import functools
import importlib
import sys
import textwrap

import typer

from printability import __version__
from printability.errors import PrintabilityError

__all__ = ["app", "main", "run"]

# Subcommand modules, in help order. Each defines register(app: typer.Typer).
SUBCOMMANDS: tuple[str, ...] = (
    "printability.cli.analyze",
    "printability.cli.stream",
    "printability.cli.demo",
    "printability.cli.simulate",
    "printability.cli.postprocess",
    "printability.cli.generate",
    "printability.cli.warmup",
    "printability.cli.serve",
)

app = typer.Typer(
    name="printability",
    help="What of your part will this nozzle actually print, and how to print exactly that.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
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


def error_paragraph(exc: BaseException) -> str:
    """One paragraph, wrapped for a terminal."""
    text = " ".join(str(exc).split())
    return textwrap.fill(f"printability: error: {text}", width=100)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code.

    ``postprocess`` is first offered to a running ``printability serve``
    (:func:`printability.server_client.run_remote`: the same file, messages and
    exit code, without the libraries' start), then run here by :func:`run`.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ["postprocess"]:
        from printability.server_client import run_served

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
        from printability._jit_cache import announce_first_compile

        # the first run after an install or an upgrade: say why nothing happens, when the
        # first kernel actually compiles (not before a bad argument's one-paragraph error)
        announce_first_compile(lambda msg: print(msg, file=sys.stderr, flush=True))
    try:
        _command()(args=argv, prog_name="printability", standalone_mode=True)
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except PrintabilityError as exc:
        print(error_paragraph(exc), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("printability: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
