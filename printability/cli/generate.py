"""``printability generate``: layers to a complete G-code file for a T-T-R machine."""

from __future__ import annotations

from pathlib import Path

import typer

from printability.cli.common import choices_help, note_default_layer_height
from printability.options import FEED_POLICIES

__all__ = ["generate_command", "register"]


def generate_command(
    input: Path = typer.Argument(..., help="Part: .stl/.3mf/.obj (sliced at --layer-height), "  # noqa: B008
                                 ".svg/.dxf/.geojson/.wkt, a slice-outline .txt or .gcode."),
    nozzle: str = typer.Option(..., "--nozzle", "-n",
                               help="Nozzle SPEC: ellipse:major=0.8,minor=0.3, rect:w=0.8,h=0.3, "
                                    "circle:d=0.4, polygon:FILE.svg."),
    machine: str = typer.Option(..., "--machine", "-m",
                                help="Machine SPEC: ttr, ttr:min=-90,max=90, a built-in profile "
                                     "or a TOML file (temperatures, speeds, retraction, G-code)."),
    output: Path = typer.Option(..., "--output", "-o", help="The G-code file to write."),  # noqa: B008
    layer_height: float | None = typer.Option(None, "--layer-height",
                                              help="Slice meshes at this layer height, mm."),
    first_layer_height: float | None = typer.Option(None, "--first-layer-height",
                                                    help="First layer height for meshes, mm."),
    units: str | None = typer.Option(None, "--units",
                                     help="Units of a mesh or drawing without units (mm, in...)."),
    perimeters: int = typer.Option(2, "--perimeters", help="Wall loops per layer."),
    infill_angle: float = typer.Option(45.0, "--infill-angle",
                                       help="Infill direction on the first layer, degrees."),
    feed_policy: str | None = typer.Option(
        None, "--feed-policy",
        help=choices_help(FEED_POLICIES, "Feed-rate policy (default: the machine's).")),
    unwind: bool = typer.Option(False, "--unwind/--no-unwind",
                                help="Cabled head: bring the rotary axis back towards 0 on "
                                     "travel moves."),
    absolute_e: bool = typer.Option(False, "--absolute-e", help="M82 absolute E (default M83)."),
    center: bool = typer.Option(True, "--center/--no-center",
                                help="Move the part to the middle of the machine's bed."),
) -> None:
    """Plan walls and infill inside what the nozzle can print, choose the nozzle angle of every
    move (widest bead that fits), order regions to cut travel, and write the G-code."""
    from printability.generate import GenerateOptions, generate_file

    opts = GenerateOptions(perimeters=perimeters, infill_angle=infill_angle,
                           feed_policy=FEED_POLICIES.check(feed_policy) if feed_policy else None,
                           unwind=unwind, relative_e=not absolute_e, center=center)
    res = generate_file(input, output, nozzle, machine, options=opts, layer_height=layer_height,
                        first_layer_height=first_layer_height, units=units)
    note_default_layer_height(input, layer_height)  # once the mesh is read
    typer.echo(f"{res.path}: {res.layers} layers, {res.lines} lines, "
               f"{res.extruded_length:.1f} mm extruded, {res.dropped_length:.2f} mm the nozzle "
               f"cannot print, {res.rotations} turns; {res.elapsed:.2f} s")
    if res.print_time is not None:
        from gcode.printtime import format_duration

        typer.echo(f"  print time on the firmware's planner (estimated): "
                   f"{format_duration(res.print_time)}")


def register(app: typer.Typer) -> None:
    """Add ``generate`` to the ``printability`` command."""
    app.command("generate")(generate_command)
