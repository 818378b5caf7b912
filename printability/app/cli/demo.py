"""``printability demo``: the whole pipeline on bundled data against the built-in simulator.

A thin adapter over :func:`printability.app.demo.run_demo`.
"""

from __future__ import annotations

from pathlib import Path

import typer

__all__ = ["demo_command", "register"]


def demo_command(
    out: Path = typer.Option(Path("printability-demo"), "--out", "-o",  # noqa: B008
                             help="Folder for the report (created; files are replaced)."),
    part: Path | None = typer.Option(None, "--part",  # noqa: B008
                                     help="Use this part instead of the bundled comb (any "
                                          "input analyze reads)."),
    nozzle: list[str] = typer.Option(  # noqa: B008
        ["circle:d=0.8", "ellipse:major=0.8,minor=0.4"], "--nozzle", "-n",
        help="Candidate nozzle SPEC, repeatable; the best ranked is printed."),
    machine: str = typer.Option("ttr", "--machine", "-m", help="Machine SPEC or profile."),
    faults: str = typer.Option("", "--faults",
                               help="Faults on the simulated serial link, e.g. "
                                    "'corrupt~0.01,drop-ok~0.005,disconnect@900'."),
    seed: int = typer.Option(0, "--seed", help="Seed of the random faults."),
) -> None:
    """Slice the bundled part, rank the nozzles, generate rotary-axis G-code for the best,
    stream it to the built-in simulator and report target, predicted and deposited layers."""
    from printability.app.demo import run_demo

    result = run_demo(out, part=part, nozzles=nozzle, machine=machine, faults=faults, seed=seed,
                      on_step=lambda m: typer.echo(f"demo: {m}", err=True))
    # the same quantity and unit as analyze's table: a volume over several layers
    volume = bool(result.ranking) and "lost_volume" in result.ranking[0]
    key, unit, frac = (("lost_volume", "mm³", "lost_volume_fraction") if volume
                       else ("lost_area", "mm²", "lost_fraction"))
    typer.echo(f"nozzles ranked by lost {'volume' if volume else 'area'}:")
    for r in result.ranking:
        typer.echo(f"  {r['rank']}. {r['nozzle']:32} lost {r[key]:9.4g} {unit} "
                   f"({100 * r[frac]:.2f} %)")
    s = result.stream
    typer.echo(f"printed {result.nozzle} on {result.machine}: {s.acknowledged}/{s.total} "
               f"commands, {s.resends} resends, {s.timeouts} timeouts, {s.reconnects} "
               f"reconnects; simulator log equals the file: "
               f"{'yes' if result.log_matches else 'NO'}")
    if result.lost_in_reset:
        typer.echo(f"the board's reset dropped {result.lost_in_reset} planned moves it had "
                   "acknowledged (as a real board would); the record lists them")
    from printability.app.demo import format_layer_table

    typer.echo(format_layer_table(result.layers))
    typer.echo(f"report: {result.report}")


def register(app: typer.Typer) -> None:
    """Add ``demo`` to the CLI."""
    app.command("demo")(demo_command)
