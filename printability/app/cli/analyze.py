"""``printability analyze``: rank nozzles on a sliced part (docs/design.md §4)."""

from __future__ import annotations

from pathlib import Path

import typer

from printability.app.cli.common import (
    choices_help,
    note_default_layer_height,
    progress_callback,
    spec_epilog,
    write_json_atomic,
)
from printability.options import ENGINES

__all__ = ["register"]


def analyze_command(
    input: Path = typer.Argument(..., help="Part: .gcode/.bgcode, .stl/.3mf/.obj, "  # noqa: B008
                                 ".svg/.dxf/.geojson/.wkt, a slice-outline .txt or a "
                                 "multi-layer slice SVG."),
    nozzle: list[str] = typer.Option(  # noqa: B008
        ["circle:d=0.4"], "--nozzle", "-n", metavar="SPEC",
        help="A candidate nozzle, repeatable: circle:d=0.4, ellipse:major=0.8,minor=0.3, "
             "rect:w=0.8,h=0.3, polygon:FILE.svg (all forms below)."),
    machine: str = typer.Option("xy", "--machine", "-m", metavar="SPEC",
                                help="The machine: xy, ttr, ttr:min=-90,max=90, a built-in "
                                     "profile or a TOML file (below)."),
    resolution: float = typer.Option(0.05, "--resolution", help="Raster grid spacing, mm."),
    angle_step: float | None = typer.Option(None, "--angle-step",
                                            help="Rotary sampling step, degrees (default: the "
                                                 "machine's)."),
    engine: str = typer.Option("auto", "--engine", help=choices_help(ENGINES, "MMC engine.")),
    layer_height: float | None = typer.Option(None, "--layer-height",
                                              help="Slice meshes at this layer height, mm."),
    first_layer_height: float | None = typer.Option(None, "--first-layer-height",
                                                    help="First layer height for meshes, mm."),
    units: str | None = typer.Option(None, "--units",
                                     help="Units of a mesh or drawing without units (mm, in...)."),
    fit: float | None = typer.Option(None, "--fit",
                                     help="Scale a drawing or map so its longest side is FIT mm."),
    map_scale: float | None = typer.Option(None, "--map-scale",
                                           help="Geographic input: mm on the print per km."),
    clip: str | None = typer.Option(None, "--clip", help="GeoJSON/WKT: keep what lies in the box "
                                    "MINX,MINY,MAXX,MAXY (file coordinates, lon/lat for maps)."),
    keep_largest: int | None = typer.Option(None, "--keep-largest",
                                            help="GeoJSON/WKT: keep the N largest polygons."),
    layers_spec: str | None = typer.Option(None, "--layers",
                                           help="Analyse only these layers (0 = bottom): "
                                                "indices, ranges A-B or slices START:STOP:STEP, "
                                                "comma-separated, e.g. 12 or 0:40:5."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the result as JSON here."),  # noqa: B008
    out: Path | None = typer.Option(None, "--out", help="Write an HTML report with figures and "  # noqa: B008
                                    "the as-built geometry into this folder."),
    workers: int = typer.Option(0, "--workers", "-j", min=0,
                                help="Parallel processes for layers; 0 (default) uses every "
                                     "core this process may run on."),
    scheduler: str | None = typer.Option(None, "--scheduler",
                                         help="Dask scheduler address to run layers on a cluster."),
    max_memory: str | None = typer.Option(None, "--max-memory",
                                          help="Memory a computation may use, e.g. 512M or 8G "
                                               "(default: half the RAM, at most 16G); larger "
                                               "work is refused before it starts."),
    bound_tolerance: str | None = typer.Option(
        None, "--bound-tolerance", metavar="TOL",
        help="Refine until each nozzle's certified interval [lo, hi] of what it loses is at "
             "most TOL wide: a width in the table's unit (mm² for one layer, mm³ for several), "
             "e.g. 0.5, or a percentage of the lost amount, e.g. 5% (floor: 1/100 of that "
             "percentage of the part, so 5% allows 0.05% of the part). Refused up front, with "
             "the estimate, when it would need more than --max-memory."),
    separate_ties: bool = typer.Option(
        False, "--separate-ties/--no-separate-ties",
        help="Refine the nozzles whose certified intervals overlap until they separate (at "
             "most --refine-budget times the first pass's work)."),
    refine_budget: float = typer.Option(
        4.0, "--refine-budget", min=0.0, metavar="FACTOR",
        help="Work --separate-ties may add, as a multiple of the first pass's work."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Compute, per layer and per nozzle, the motion restriction P, the as-built layer S and
    what is lost; print the nozzles ranked by what they lose (area for one layer, volume for
    several)."""
    from printability.analysis import RefineOptions, analyze, select_layers
    from printability.settings import Settings
    from printability.sources import load_layers

    limits = {} if max_memory is None else {"max_memory": parse_size(max_memory)}
    settings = Settings(resolution=resolution, angle_step=angle_step, **limits,
                        workers=workers or local_cores(),
                        progress=progress)
    engine = ENGINES.check(engine)
    box = _parse_box(clip) if clip is not None else None
    layers = load_layers(input, layer_height=layer_height, first_layer_height=first_layer_height,
                         units=units, fit=fit, map_scale=map_scale, clip=box,
                         keep_largest=keep_largest, settings=settings)
    note_default_layer_height(input, layer_height)  # once the mesh is read
    if layers_spec is not None:
        layers = select_layers(layers, layers_spec)
    for warning in layers.meta.get("warnings", ()):
        typer.echo(f"printability: warning: {warning}", err=True)
    refine = RefineOptions(bound_tolerance=bound_tolerance, separate_ties=separate_ties,
                           refine_budget=refine_budget)
    with progress_callback("analysing layers", enabled=progress) as on_progress:
        result = analyze(layers, nozzle, machine, engine=engine, settings=settings,
                         keep_results=out is not None, scheduler=scheduler,
                         on_progress=on_progress, refine=refine)
    print_ranking(result)
    for line in ranking_notes(result, suggest=not separate_ties):
        typer.echo(line)
    if json_out is not None:
        write_json_atomic(json_out, result.to_json())
    if out is not None:
        from printability.analysis.report import write_report

        index = write_report(result, out)
        typer.echo(f"report: {index}")


_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_size(text: str) -> int:
    """Bytes from a size such as ``512M``, ``8G``, ``1.5G`` or ``1000000`` (binary units)."""
    from printability.errors import InputError

    t = text.strip().upper().removesuffix("IB").removesuffix("B")
    unit = t[-1:] if t[-1:] in _UNITS and t[-1:] else ""
    try:
        value = float(t[: len(t) - len(unit)])
    except ValueError:
        value = -1.0
    if not value > 0 or value * _UNITS[unit] < 1 or not value * _UNITS[unit] <= 1 << 50:
        raise InputError(f"--max-memory expects a positive size up to 1P such as 512M or 8G; "
                         f"found {text!r}")
    return int(value * _UNITS[unit])


def local_cores() -> int:
    """Cores this process may run on (its CPU affinity), at least 1."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _parse_box(text: str) -> tuple[float, float, float, float]:
    from printability.errors import InputError

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or values[0] >= values[2] or values[1] >= values[3]:
        raise InputError(f"--clip expects MINX,MINY,MAXX,MAXY with MINX < MAXX and MINY < MAXY; "
                         f"found {text!r}")
    return values  # type: ignore[return-value]


def ranking_table(result):
    """The ranking as a rich Table: one unit throughout (:mod:`printability.analysis.ranking`).

    Several layers with heights are compared by volume, so the lost amount, its share and
    its certified bounds are all volumes (mm³); one layer, or layers without a height, by
    area (mm²). The rank column shows the ranks the certified bounds allow: ``1–2`` when a
    nozzle's interval overlaps another's (tied within the certified bounds).

    Parameters
    ----------
    result : printability.analysis.Analysis
        The ranked analysis.

    Returns
    -------
    rich.table.Table
    """
    from rich import box
    from rich.table import Table

    from printability.analysis.ranking import rank_label, totals, uses_volume

    volume = uses_volume([lay.height for lay in result.layers])
    unit = "mm³" if volume else "mm²"
    n_layers = len(result.layers)
    what = (f"lost volume: Σ over {n_layers} layers of the lost area × the layer height"
            if volume else "lost area" + (f": Σ over {n_layers} layers" if n_layers > 1 else ""))
    caption = f"{what}; bounds: the certified interval of that figure"
    if result.ties:
        caption += "; rank A–B: tied within the certified bounds (their intervals overlap)"
    table = Table(title=f"{result.input} — machine {result.machine.spec}, engine {result.engine}, "
                        f"{n_layers} layer(s)",
                  caption=caption, box=box.SIMPLE_HEAD, pad_edge=False)
    # in a narrow terminal the headers wrap, never the nozzle SPEC: a reader copies it
    widest = max((len(n.nozzle.spec) for n in result.nozzles), default=6)
    table.add_column("rank", justify="right", no_wrap=True)
    table.add_column("nozzle", justify="left", no_wrap=True, min_width=min(widest, 48))
    for col in (f"lost\n{unit}", "lost\n%", f"bounds\n{unit}", "compo-\nnents", "build\ntime"):
        table.add_column(col, justify="right", overflow="fold")
    for n in result.nozzles:
        t = totals(n.layers, volume=volume)
        lo, hi = t.lost_bounds
        label = rank_label(n.rank_range) if n.rank_range != (0, 0) else str(n.rank)
        table.add_row(label, n.nozzle.spec, f"{t.lost:.4g}", f"{100 * t.lost_fraction:.2f}",
                      f"[{lo:.4g}, {hi:.4g}]", str(n.components), _duration(n.build_time))
    return table


def ranking_notes(result, *, suggest: bool = True) -> list[str]:
    """Lines printed under the table: ties, and what refinement met and cost.

    Parameters
    ----------
    result : printability.analysis.Analysis
        The ranked analysis.
    suggest
        Whether to suggest ``--separate-ties`` for tied nozzles.

    Returns
    -------
    list of str
    """
    lines = []
    unit = "mm³" if result.quantity == "volume" else "mm²"
    for a, b in result.ties:
        lines.append(f"tied within the certified bounds: {a} and {b} (their intervals overlap; "
                     "the order of their estimates is not certain)"
                     + ("; --separate-ties refines them" if suggest else ""))
    ref = result.refinement
    if ref is not None:
        if ref.tolerance is not None:
            widths = ", ".join(
                f"{n.nozzle.spec} {_width(n):.3g} ≤ {n.allowed_width:.3g} {unit}"
                if n.tolerance_met else
                f"{n.nozzle.spec} {_width(n):.3g} > {n.allowed_width:.3g} {unit}"
                for n in result.nozzles)
            lines.append(f"bound tolerance {ref.tolerance}: "
                         + ("met" if ref.met else f"not met ({ref.stopped})") + f": {widths}")
        if ref.rounds or ref.separate_ties or ref.tolerance is not None:
            finest = min((o.resolution for n in result.nozzles for o in n.layers
                          if o.refinements and o.engine == "raster"), default=None)
            lines.append(
                f"refinement: {ref.rounds} round(s), {ref.tasks} layer computation(s), "
                f"{ref.elapsed:.1f} s" + (f", finest resolution {finest:g} mm"
                                           if finest is not None else "")
                + f"; stopped: {ref.stopped}")
        lines.extend(f"refinement: {note}" for note in ref.notes)
    return lines


def print_ranking(result) -> None:
    """The ranking table (:func:`ranking_table`) on stdout."""
    import sys

    from rich.console import Console

    # a pipe or a file gets the whole table, not one wrapped to 80 columns
    Console(width=None if sys.stdout.isatty() else 140).print(ranking_table(result))


def _width(n) -> float:
    lo, hi = n.totals().lost_bounds
    return hi - lo


def _duration(seconds: float) -> str:
    m, s = divmod(round(seconds), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


def register(app: typer.Typer) -> None:
    """Add ``analyze`` to the ``printability`` command."""
    app.command("analyze", epilog=spec_epilog())(analyze_command)
