"""``printability postprocess``: turn a slicer's G-code into rotary-axis G-code (docs/design.md §4).

Run by a PrusaSlicer-family slicer as a post-processing script, the G-code
path is the last argument and the file is rewritten in place; the slicer's
``SLIC3R_*`` settings come from the environment, options given here override
them. Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7, recognised by its content)
is written back as binary G-code with the same compression and encoding.
"""

from __future__ import annotations

from pathlib import Path

import typer

from printability.app.cli.common import (
    choices_help,
    spec_epilog,
    stage_progress,
    stop_signals_raise,
)
from printability.options import CORNER_PIECES, E_POLICIES, FEED_POLICIES, SERVER_POLICIES

__all__ = ["postprocess_command", "register"]


def postprocess_command(
    gcode: Path = typer.Argument(..., help="The slicer's G-code file, text or binary "  # noqa: B008
                                 "(.bgcode; rewritten in place unless -o is given)."),
    nozzle: str | None = typer.Option(
        None, "--nozzle", "-n", metavar="SPEC",
        help="The nozzle: ellipse:major=0.8,minor=0.3, rect:w=0.8,h=0.3, circle:d=0.4, "
             "polygon:FILE.svg (all forms below). Default: a round nozzle of the slicer's "
             "nozzle_diameter."),
    machine: str = typer.Option("ttr", "--machine", "-m", metavar="SPEC",
                                help="The machine: ttr, ttr:min=-90,max=90, xy, a built-in "
                                     "profile or a TOML file (below)."),
    output: Path | None = typer.Option(None, "--output", "-o",  # noqa: B008
                                       help="Write here instead of in place."),
    tolerance: float = typer.Option(1e-3, "--tolerance",
                                    help="How far a bead may stand outside the layer, mm."),
    feed_policy: str | None = typer.Option(
        None, "--feed-policy",
        help=choices_help(FEED_POLICIES, "Feed-rate policy (default: the machine's).")),
    letter: str | None = typer.Option(None, "--letter", help="Rotary axis letter (default: "
                                      "the machine's, C)."),
    unwind: bool = typer.Option(False, "--unwind/--no-unwind",
                                help="Cabled head: bring the rotary axis back towards 0 on "
                                     "travel moves."),
    allow_empty: bool = typer.Option(False, "--allow-empty",
                                     help="Write the file even when the nozzle prints none "
                                          "of the part (by default: an error, file "
                                          "untouched)."),
    corner_pieces: str = typer.Option(
        "drop", "--corner-pieces",
        help=choices_help(CORNER_PIECES, "What to do with the short pieces beside an outer "
                                         "wall's corners that need a turn of their own.")),
    e_policy: str = typer.Option("width", "--e-policy",
                                 help=choices_help(E_POLICIES, "How E follows the bead width.")),
    filament_diameter: float | None = typer.Option(None, "--filament-diameter",
                                                   help="mm (default: the slicer's)."),
    layer_height: float | None = typer.Option(None, "--layer-height",
                                              help="mm (default: the file's)."),
    output_name: str | None = typer.Option(
        None, "--output-name",
        help="Ask the slicer to save the result under this name (written to "
             "<gcode>.output_name, PrusaSlicer >= 2.4)."),
    workers: int = typer.Option(0, "--workers", "-j", min=0,
                                help="Threads (0: one per CPU core, at most 4); the output is "
                                     "the same on any number."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Show the stage and the layers planned on stderr (in a "
                                       "terminal)."),
    server: str = typer.Option(
        "use", "--server",
        help=choices_help(SERVER_POLICIES, "Hand the run to `printability serve`, which "
                                           "skips the libraries' start.")),
) -> None:
    """Choose the nozzle angle of every extruding move so that nothing lands outside the part
    and the bead width matches the slicer's plan; keep every other line byte for byte."""
    from printability.planning.orientation import OrientationOptions
    from printability.postprocess import PostprocessOptions, postprocess_file

    SERVER_POLICIES.check(server)  # the hand-over was decided before this (server_client)

    opts = PostprocessOptions(
        nozzle=nozzle, machine=machine, tolerance=tolerance,
        feed_policy=FEED_POLICIES.check(feed_policy) if feed_policy else None,
        letter=letter, unwind=unwind, e_policy=E_POLICIES.check(e_policy),
        filament_diameter=filament_diameter, layer_height=layer_height, output_name=output_name,
        workers=workers or None, allow_empty=allow_empty,
        orientation=OrientationOptions(
            side_piece_widths=0.0 if CORNER_PIECES.check(corner_pieces) == "keep"
            else OrientationOptions().side_piece_widths),
    )
    with stop_signals_raise(f"{gcode} is unchanged"), \
            stage_progress(enabled=progress and not quiet) as on_progress:
        res = postprocess_file(gcode, options=opts, output=output, on_progress=on_progress)
    if quiet:
        return
    if res.already_processed:
        typer.echo(f"{gcode}: already post-processed by printability; left unchanged")
        return
    typer.echo(
        f"{res.output}: {res.lines_in} lines in, {res.lines_out} out; {res.changed_lines} "
        f"rewritten, {res.inserted_lines} inserted, {res.rotary_words} rotary words; "
        f"{res.split_moves} moves shortened and {res.dropped_moves} dropped "
        f"({res.dropped_length:.2f} mm not printed); {res.elapsed:.2f} s"
    )
    if res.binary:
        typer.echo(f"  written as {res.binary}, as it came (lines counted in its G-code)")
    if res.print_time_in and res.print_time_out is not None:
        from gcode.printtime import format_duration

        typer.echo(f"  print time on the firmware's planner (estimated): "
                   f"{format_duration(res.print_time_in)} as sliced, "
                   f"{format_duration(res.print_time_out)} rewritten "
                   f"({res.print_time_out / res.print_time_in:.2f}x)")
    lossy = [r for r in res.layers if r.dropped_moves or r.split_moves]
    if lossy:
        worst = max(lossy, key=lambda r: r.dropped_length)
        typer.echo(f"  {len(lossy)} of {len(res.layers)} layers lose something (per-layer "
                   f"counts in the file's header); worst: z={worst.z:.3f}, "
                   f"{worst.dropped_length:.3f} mm not printed")


def register(app: typer.Typer) -> None:
    """Add ``postprocess`` to the ``printability`` command."""
    app.command("postprocess", epilog=spec_epilog())(postprocess_command)
