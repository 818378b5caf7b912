"""``printability generate``: layers to a complete G-code file for a T-T-R machine."""

from __future__ import annotations

import textwrap
from pathlib import Path

import typer

from printability.app.cli.common import (
    choices_help,
    note_default_layer_height,
    spec_epilog,
    stage_progress,
)
from printability.options import FEED_POLICIES

__all__ = ["generate_command", "register"]


def generate_command(
    input: Path = typer.Argument(..., help="Part: .stl/.3mf/.obj (sliced at --layer-height), "  # noqa: B008
                                 ".svg/.dxf/.geojson/.wkt, a slice-outline .txt or .gcode."),
    nozzle: str = typer.Option(..., "--nozzle", "-n", metavar="SPEC",
                               help="The nozzle: ellipse:major=0.8,minor=0.3, rect:w=0.8,h=0.3, "
                                    "circle:d=0.4, polygon:FILE.svg (all forms below)."),
    machine: str = typer.Option(..., "--machine", "-m", metavar="SPEC",
                                help="The machine: ttr, ttr:min=-90,max=90, a built-in profile "
                                     "or a TOML file (temperatures, speeds, retraction, "
                                     "G-code; below)."),
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
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Show the stage and the layers planned on stderr (in a "
                                       "terminal)."),
) -> None:
    """Plan walls and infill inside what the nozzle can print, choose the nozzle angle of every
    move (widest bead that fits), order regions to cut travel, and write the G-code."""
    from printability.generate import GenerateOptions, generate_file

    opts = GenerateOptions(perimeters=perimeters, infill_angle=infill_angle,
                           feed_policy=FEED_POLICIES.check(feed_policy) if feed_policy else None,
                           unwind=unwind, relative_e=not absolute_e, center=center)
    with stage_progress(enabled=progress) as on_progress:
        res = generate_file(input, output, nozzle, machine, options=opts,
                            layer_height=layer_height, first_layer_height=first_layer_height,
                            units=units, on_progress=on_progress)
    note_default_layer_height(input, layer_height)  # once the mesh is read
    typer.echo(f"{res.path}: {res.layers} layers, {res.lines} lines, "
               f"{res.extruded_length:.1f} mm of bead extruded, {res.rotations} turns; "
               f"{res.elapsed:.2f} s")
    typer.echo(textwrap.fill(left_out_summary(res), width=88, initial_indent="  ",
                             subsequent_indent="    "))
    if res.print_time is not None:
        from gcode.printtime import format_duration

        typer.echo(f"  print time on the firmware's planner (estimated): "
                   f"{format_duration(res.print_time)}")


def left_out_summary(res) -> str:
    """What the generated paths leave out, said as what it measures.

    ``generate`` plans walls (at the nozzle's narrowest bead) and infill inside the part, then
    drops the pieces of path where no nozzle angle keeps the bead inside it: a *length*. The
    file's header turns it into an area, that length times the wall width, which it calls
    "lost area"; it is not ``analyze``'s lost area λ(G \\ S), what no position of the nozzle
    covers at all, whatever the paths.

    Parameters
    ----------
    res : printability.generate.GenerateResult
        The generation's result (``dropped_length`` in mm, ``summary`` per layer with the
        header's ``lost_area`` in mm²).

    Returns
    -------
    str
        One sentence.
    """
    if res.dropped_length <= 0:
        return ("left out: nothing; every planned wall and infill path is printed (analyze "
                "reports what no nozzle position covers, λ(G \\ S))")
    area = sum(row.get("lost_area", 0.0) for row in res.summary)
    return (f"left out: {res.dropped_length:.2f} mm of planned path where no nozzle angle keeps "
            f"the bead inside the part (× the {area / res.dropped_length:.2f} mm wall width = "
            f"{area:.3f} mm², the file header's \"lost area\"; analyze's lost area, "
            "λ(G \\ S), is what no nozzle position covers, whatever the paths)")


def register(app: typer.Typer) -> None:
    """Add ``generate`` to the ``printability`` command."""
    app.command("generate", epilog=spec_epilog())(generate_command)
