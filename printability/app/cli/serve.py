"""``printability serve``: keep a warm process for the slicer plug-in's post-processing.

A thin adapter over :mod:`printability.app.server` (the address, messages and
fall-back rule are documented in :mod:`printability.app.server_client`).
"""

from __future__ import annotations

import typer

__all__ = ["register", "serve_command"]


def serve_command(
    socket_path: str | None = typer.Option(
        None, "--socket",
        help="Socket path (default: $PRINTABILITY_SERVER, else a private per-user path)."),
    idle_timeout: float | None = typer.Option(
        None, "--idle-timeout", min=0.0,
        help="Stop after this many seconds without a request (default: never)."),
    warm: bool = typer.Option(True, "--warm/--no-warm",
                              help="Load the compiled kernels before the first request."),
    status: bool = typer.Option(False, "--status", help="Tell whether a server is running."),
    stop: bool = typer.Option(False, "--stop", help="Stop the running server."),
) -> None:
    """Serve the slicer plug-in (`printability-postprocess`) from one warm process, so that
    each export pays the work and not the start of the libraries (about 2 s). The plug-in
    uses the server when one is running and otherwise runs on its own."""
    from printability.app.server import serve, server_status, stop_server
    from printability.app.server_client import default_address

    address = socket_path or default_address()
    if address is None and (status or stop):
        typer.echo("no server: PRINTABILITY_SERVER is 'off' or this Python has no Unix-domain "
                   "sockets")
        raise typer.Exit(1)
    if status:
        info = server_status(address)
        if info is None:
            typer.echo(f"no server at {address}")
            raise typer.Exit(1)
        typer.echo(f"server at {address}: pid {info['pid']}, printability {info['version']}, "
                   f"{info['python']}")
        return
    if stop:
        if not stop_server(address):
            typer.echo(f"no server at {address}")
            raise typer.Exit(1)
        typer.echo(f"server at {address} stopped")
        return
    res = serve(address=address, idle_timeout=idle_timeout, warm=warm, retain_memory=True,
                on_event=lambda msg: typer.echo(f"printability serve: {msg}", err=True))
    typer.echo(f"served {res.requests} requests in {res.seconds:.0f} s ({res.reason})")


def register(app: typer.Typer) -> None:
    """Add ``serve`` to the ``printability`` command."""
    app.command("serve")(serve_command)
