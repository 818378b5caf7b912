"""``printability warmup``: compile and cache the kernels before the first slicer export.

A thin adapter over :func:`printability.app.warmup.warm_up`.
"""

from __future__ import annotations

import typer

__all__ = ["register", "warmup_command"]


def warmup_command() -> None:
    """Compile the kernels the slicer plug-in and ``generate`` use and cache them (about a
    minute, once after installing or upgrading; seconds afterwards), so that a slicer's
    first export does not wait for it."""
    from printability.app.warmup import warm_up

    res = warm_up(on_run=lambda what, machine: typer.echo(f"warm-up: {what} on {machine}",
                                                         err=True), generate=True)
    typer.echo(f"kernels compiled and cached: {len(res.runs)} runs in {res.seconds:.1f} s")


def register(app: typer.Typer) -> None:
    """Add ``warmup`` to the ``printability`` command."""
    app.command("warmup")(warmup_command)
