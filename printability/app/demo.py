"""The whole pipeline on bundled data, against the built-in simulator (``printability demo``).

1. **Layers** — the bundled part, a comb whose fins are 0.5 to 2.5 mm wide
   (``printability/data/demo/comb.stl``, 26 × 12 × 0.8 mm), sliced at 0.2 mm
   and moved to the middle of the machine's bed.
2. **Analysis and ranking** — :func:`printability.analysis.analyze` computes,
   per layer and per candidate nozzle, the motion restriction P, the as-built
   layer S and what is lost, and ranks the nozzles.
3. **G-code with the rotary axis** — :func:`printability.generate.generate_gcode`
   plans walls and infill for the best nozzle and turns it (C axis) so that it
   never lays material outside the part.
4. **Streaming** — :class:`machine_io.Host` sends the file over a pty to the
   virtual printer (:mod:`simulators`, Marlin protocol with ADVANCED_OK),
   optionally with injected faults, and checks that the printer executed
   every command once, in order.
5. **Report** — per layer: the target G, the predicted as-built S and what the
   simulator actually deposited D, with D's area outside G (the MMC promise:
   zero) and how much of S it covers; a JSON file, an HTML page with a
   figure, the G-code, the simulator's record and the serial transcript, each
   written atomically into the output folder.

Everything used is installed by ``pip install -e '.[all]'`` (matplotlib for
the figure comes with the ``report`` extra; without it the page has no figure).
"""

from __future__ import annotations

import html
import io
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import shapely
import shapely.affinity

from printability.base.files import write_atomic
from printability.errors import PrintabilityOSError, PrinterError
from printability.model.layers import LayerStack

__all__ = ["DEFAULT_NOZZLES", "DEMO_PART", "LAYER_COLUMNS", "DemoLayer", "DemoResult",
           "format_layer_table", "run_demo"]

DEMO_PART = Path(__file__).parents[1] / "data" / "demo" / "comb.stl"
"""The bundled part: a comb with fins 0.5, 0.7, 0.9, 1.2, 1.6, 2.0 and 2.5 mm wide."""

DEFAULT_NOZZLES: tuple[str, ...] = ("circle:d=0.8", "ellipse:major=0.8,minor=0.4")
"""Two nozzles of the same length: round, or elliptical and turned by the rotary axis."""


@dataclass(frozen=True)
class DemoLayer:
    """Target, prediction and deposition of one layer (areas in mm²).

    Attributes
    ----------
    z
        Layer top, mm.
    target_area
        λ(G).
    predicted_area
        λ(S) predicted by the analysis for the chosen nozzle (its best estimate).
    deposited_area
        λ(D), what the simulator deposited.
    outside_area
        λ(D \\ G) beyond a 1 µm tolerance: material outside the part (0 keeps the MMC promise).
    covered_target
        λ(D ∩ G) / λ(G).
    covered_prediction
        λ(D ∩ S) / λ(S) with the engine's S geometry (for the raster engine its inner
        estimate S_inner ⊆ S): how much of the predicted layer was actually printed.
    """

    z: float
    target_area: float
    predicted_area: float
    deposited_area: float
    outside_area: float
    covered_target: float
    covered_prediction: float

    def to_json(self) -> dict[str, float]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class DemoResult:
    """What the demo did; the files are in ``out_dir``."""

    out_dir: Path
    files: tuple[Path, ...]
    ranking: tuple[dict[str, Any], ...]
    nozzle: str
    machine: str
    gcode_lines: int
    stream: Any  # machine_io.StreamReport
    log_matches: bool
    layers: tuple[DemoLayer, ...]
    violations: int
    elapsed: float
    notes: tuple[str, ...] = field(default=())
    lost_in_reset: int = 0  # acknowledged planned moves a board reset dropped unprinted

    @property
    def report(self) -> Path:
        return self.out_dir / "report.html"


def _write_atomic(path: Path, data: bytes | str) -> Path:
    write_atomic(path, data)  # keeps an existing file's mode and owner; 0666 less the umask
    return path


def _centered(layers: LayerStack, bed: tuple[float, float, float, float] | None) -> LayerStack:
    """The layers moved so the part sits in the middle of the bed (unchanged without a bed)."""
    if bed is None:
        return layers
    x0, y0, x1, y1 = shapely.union_all([lay.region for lay in layers]).bounds
    dx = (bed[0] + bed[1]) / 2 - (x0 + x1) / 2
    dy = (bed[2] + bed[3]) / 2 - (y0 + y1) / 2
    moved = tuple(replace(lay, region=shapely.affinity.translate(lay.region, dx, dy))
                  for lay in layers)
    return LayerStack(moved, source=layers.source, units=layers.units,
                      meta={**layers.meta, "moved_by": (dx, dy)})


def run_demo(
    out_dir: str | os.PathLike[str],
    *,
    part: str | os.PathLike[str] | None = None,
    nozzles: Sequence[str] = DEFAULT_NOZZLES,
    machine: str = "ttr",
    layer_height: float = 0.2,
    faults: str = "",
    seed: int = 0,
    on_step: Callable[[str], None] | None = None,
) -> DemoResult:
    """Run the pipeline end to end and write the report into ``out_dir``.

    Parameters
    ----------
    out_dir
        Folder for the report (created; files in it are replaced atomically).
    part
        A part to use instead of the bundled comb (any input ``analyze`` reads).
    nozzles
        Candidate nozzle SPECs; the best ranked is printed.
    machine
        Machine SPEC or profile (the simulator gets the same).
    layer_height
        Slicing of mesh inputs (STL, 3MF, OBJ), mm; other inputs keep their own layers.
    faults, seed
        Faults to inject into the simulated link (e.g. ``"corrupt~0.01,drop-ok~0.005"``).
    on_step
        Called with a one-line message as each step starts.

    Returns
    -------
    DemoResult

    Raises
    ------
    PrinterError
        The simulated printer did not execute exactly the file.
    InputError, PrintabilityOSError
        Bad options, unreadable part, unwritable folder.
    """
    from machine_io import Host, HostConfig, Transcript, executed_as_streamed, parse_program
    from printability.analysis import analyze
    from printability.generate import GenerateOptions, generate_gcode
    from printability.model.nozzle import parse_nozzle
    from printability.sources import load_layers
    from simulators import make_config, write_record
    from simulators.config import resolve_machine
    from simulators.faults import FaultPlan
    from simulators.transports import Link, PtyServer

    t0 = time.perf_counter()
    out = Path(out_dir)
    try:  # fail before the work, not after it
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PrintabilityOSError(f"{out}: cannot create the report folder "
                                  f"({exc.strerror or exc})") from None
    step = on_step or (lambda message: None)
    # Options are checked before the long steps start.
    for spec in nozzles:
        parse_nozzle(spec)
    FaultPlan.parse(faults, seed=seed)
    source = Path(part) if part is not None else DEMO_PART
    mach = resolve_machine(machine)
    step(f"layers: {source.name}")
    # a mesh is sliced at layer_height; drawings, maps and G-code bring their own layers
    sliced = source.suffix.lower() in (".stl", ".3mf", ".obj")
    layers = _centered(load_layers(source, layer_height=layer_height if sliced else None),
                       mach.bed)

    step(f"analysis: {len(layers)} layers × {len(nozzles)} nozzles on {mach.name}")
    analysis = analyze(layers, list(nozzles), mach, keep_results=True)
    best = analysis.nozzles[0]
    ranking = tuple(_ranking_row(n) for n in analysis.nozzles)

    step(f"G-code: {best.nozzle.spec} (ranked first)")
    text, gen = generate_gcode(layers, best.nozzle, mach, options=GenerateOptions(center=False))
    files = [_write_atomic(out / "part.gcode", text)]
    program = parse_program(text.encode(), source=str(out / "part.gcode"))

    step(f"streaming {len(program)} commands to the simulator"
         + (f" with faults {faults}" if faults else ""))
    link = Link(make_config(profile="marlin-advanced", machine=mach, nozzle=best.nozzle,
                            clock="sim", faults=faults, seed=seed, target=layers))
    server = PtyServer(link)
    transcript_path = out / "serial.log"
    with server, Host(server.path, config=HostConfig(reply_timeout=1.0, confirm_timeout=0.3),
                      transcript=Transcript(transcript_path)) as host:
        host.connect()
        report = host.stream(program)
    files.append(transcript_path)
    # The file travels as numbered lines; the host's own queries (M115, M114) are
    # unnumbered and may be damaged on a faulty wire, then run as unknown commands.
    executed = [t for n, t in link.firmware.executed
                if n is not None and not t.startswith("M110")]
    log_matches = executed_as_streamed(executed, list(program.commands), report)
    if not log_matches:
        raise PrinterError("the simulator did not execute exactly the streamed file (see "
                           f"{transcript_path}); the host lost or repeated a command")
    record = link.firmware.record()
    files.append(write_record(record, out / "record.json"))

    step("report")
    rows = _compare(layers, best, record)
    result = DemoResult(out, (), ranking, best.nozzle.spec, mach.name, len(program), report,
                        log_matches, tuple(rows), len(record.violations),
                        time.perf_counter() - t0,
                        (f"generate: {gen.rotations} rotations, {gen.dropped_length:.2f} mm of "
                         f"path no orientation can print",),
                        len(record.stats.get("lost_in_reset", ())))
    doc = _json(result, analysis, record)
    files.append(_write_atomic(out / "report.json", json.dumps(doc, indent=1) + "\n"))
    png = _figure(layers, analysis, record)
    if png is not None:
        files.append(_write_atomic(out / "layers.png", png))
    files.append(_write_atomic(out / "report.html", _html(result, png is not None)))
    return replace(result, files=tuple(files), elapsed=time.perf_counter() - t0)


def _ranking_row(n: Any) -> dict[str, Any]:
    """One nozzle's line of the ranking: areas summed over the layers (mm², the keys the
    report has always had) and, for several layers with heights, the volumes ``analyze``
    ranks by (mm³), each with its certified bounds."""
    from printability.analysis.ranking import totals

    area = totals(n.layers, volume=False)
    row: dict[str, Any] = {
        "rank": n.rank, "nozzle": n.nozzle.spec, "lost_area": n.lost_area,
        "lost_area_bounds": list(area.lost_bounds), "lost_fraction": n.lost_fraction,
        "as_built_area": n.as_built_area, "target_area": n.target_area}
    t = totals(n.layers)
    if t.quantity == "volume":
        row.update(lost_volume=t.lost, lost_volume_bounds=list(t.lost_bounds),
                   target_volume=t.target, lost_volume_fraction=t.lost_fraction)
    return row


LAYER_COLUMNS: tuple[tuple[str, str], ...] = (
    ("z", "mm"), ("target G", "mm²"), ("predicted S", "mm²"), ("deposited D", "mm²"),
    ("D outside G", "mm²"), ("D covers G", "%"), ("D covers S", "%"))
"""The per-layer comparison's columns and their units (the page's table and the terminal's)."""


def _layer_cells(row: DemoLayer) -> tuple[str, ...]:
    return (f"{row.z:.2f}", f"{row.target_area:.2f}", f"{row.predicted_area:.2f}",
            f"{row.deposited_area:.2f}", f"{row.outside_area:.4f}",
            f"{100 * row.covered_target:.1f}", f"{100 * row.covered_prediction:.1f}")


def format_layer_table(rows: Sequence[DemoLayer]) -> str:
    """The per-layer comparison as fixed-width text, each column headed by its unit.

    Parameters
    ----------
    rows
        The demo's layers (:attr:`DemoResult.layers`).

    Returns
    -------
    str
        A header of two lines (names, then units) and one line per layer, no final newline.
    """
    cells = [_layer_cells(r) for r in rows]
    widths = [max(len(name), len(unit) + 2, *(len(c[i]) for c in cells))
              for i, (name, unit) in enumerate(LAYER_COLUMNS)]
    lines = ["  ".join(name.rjust(w) for (name, _), w in zip(LAYER_COLUMNS, widths, strict=True)),
             "  ".join(f"({unit})".rjust(w)
                       for (_, unit), w in zip(LAYER_COLUMNS, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)


def _layer_at(record: Any, z: float, tol: float) -> Any:
    near = [lay for lay in record.layers if abs(lay.z - z) <= tol]
    return min(near, key=lambda lay: abs(lay.z - z)) if near else None


def _compare(layers: LayerStack, best: Any, record: Any) -> list[DemoLayer]:
    rows = []
    tol = 0.5 * min((lay.height for lay in layers if lay.height > 0), default=1.0)
    for lay, outcome in zip(layers, best.layers, strict=True):
        g = lay.region
        s = outcome.result.as_built if outcome.result is not None else None
        dep = _layer_at(record, lay.z, tol)
        d = dep.region if dep is not None else shapely.MultiPolygon()
        rows.append(DemoLayer(
            z=lay.z, target_area=float(g.area), predicted_area=float(outcome.as_built_area),
            deposited_area=float(d.area),
            outside_area=float(d.difference(g.buffer(1e-3)).area),
            covered_target=float(d.intersection(g).area / g.area) if g.area else 0.0,
            covered_prediction=(float(d.intersection(s).area / s.area)
                                if s is not None and s.area else 0.0)))
    return rows


def _json(result: DemoResult, analysis: Any, record: Any) -> dict[str, Any]:
    return {
        "format": "printability-demo", "nozzle": result.nozzle, "machine": result.machine,
        "ranking": list(result.ranking), "analysis": analysis.to_json(),
        "gcode_lines": result.gcode_lines, "stream": result.stream.to_json(),
        "simulator_log_equals_file": result.log_matches,
        "layers": [row.to_json() for row in result.layers],
        "violations": result.violations, "notes": list(result.notes),
        "simulator": record.stats,
    }


_MAX_FIGURE_LAYERS = 6
"""The figure shows at most this many layers (spread over the part)."""

_DEPOSITED, _OUTSIDE = "#7b3294", "#000000"
"""The deposition's colours: what the simulator laid, and any of it outside G."""


def _figure(layers: LayerStack, analysis: Any, record: Any) -> bytes | None:
    """Per layer, side by side: each candidate nozzle's prediction (S, and what it loses),
    then what the simulator deposited with the printed nozzle (the first ranked)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    import numpy as np
    from matplotlib.patches import Patch

    from printability.analysis.report import COLORS, draw_geometry, draw_layer, is_inner_bound

    n = len(layers)
    shown = sorted(set(np.linspace(0, n - 1, min(n, _MAX_FIGURE_LAYERS)).round().astype(int)))
    nozzles = analysis.nozzles
    x0, y0, x1, y1 = shapely.union_all([lay.region for lay in layers]).bounds
    pad = 0.04 * max(x1 - x0, y1 - y0)
    aspect = (y1 - y0 + 2 * pad) / (x1 - x0 + 2 * pad)
    cols = len(nozzles) + 1
    panel_w = 4.2
    fig, axes = plt.subplots(len(shown), cols, squeeze=False,
                             figsize=(panel_w * cols, 0.9 + len(shown) * (panel_w * aspect + 0.5)))
    tol = 0.5 * min((lay.height for lay in layers if lay.height > 0), default=1.0)
    best = nozzles[0]
    for row, i in zip(axes, shown, strict=True):
        lay = layers[i]
        for ax, noz in zip(row, nozzles, strict=False):
            o = noz.layers[i]
            draw_geometry(ax, lay.region, COLORS["target"], zorder=0)
            draw_layer(ax, o, lay.region, numbers=False)
            ax.set_title(f"{noz.nozzle.spec}{' (printed)' if noz is best else ''}\n"
                         f"z = {lay.z:.2f} mm: lost {o.lost_area:.3g} mm² "
                         f"[{o.lost_area_bounds[0]:.3g}, {o.lost_area_bounds[1]:.3g}]",
                         fontsize=8)
        ax = row[-1]
        draw_geometry(ax, lay.region, COLORS["target"], zorder=0)
        dep = _layer_at(record, lay.z, tol)
        d_area = outside_area = 0.0
        if dep is not None:
            draw_geometry(ax, dep.region, _DEPOSITED, zorder=2)
            d_area = dep.region.area
            outside = dep.region.difference(lay.region.buffer(1e-3))
            outside_area = outside.area
            draw_geometry(ax, outside, _OUTSIDE, edge=_OUTSIDE, zorder=3)
        ax.set_title(f"deposited by the simulator ({best.nozzle.spec})\n"
                     f"z = {lay.z:.2f} mm: {d_area:.4g} mm², outside G {outside_area:.2g} mm²",
                     fontsize=8)
        for a in row:
            a.set_xlim(x0 - pad, x1 + pad)
            a.set_ylim(y0 - pad, y1 + pad)
            a.set_aspect("equal")
            a.tick_params(labelsize=7)
    inner = any(o.result is not None and is_inner_bound(o.result)
                for noz in nozzles for o in noz.layers)
    handles = [Patch(color=COLORS["target"], label="target G"),
               Patch(color=COLORS["as_built"], label="predicted S"),
               Patch(color=COLORS["lost"], label="lost (G \\ S)"),
               *([Patch(color=COLORS["uncertain"], label="not proven printed (S_inner)")]
                 if inner else []),
               Patch(color=_DEPOSITED, label="deposited D"),
               Patch(color=_OUTSIDE, label="D outside G")]
    title = ("Prediction per nozzle and deposition, mm"
             + (f" ({len(shown)} of {n} layers)" if len(shown) < n else ""))
    fig.suptitle(title, fontsize=10)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _lost_note(result: DemoResult) -> str:
    if not result.lost_in_reset:
        return ""
    return (f"The board reset during the print and dropped {result.lost_in_reset} planned "
            "moves it had already acknowledged (a real board loses its planner too; the host "
            "resumes after the last acknowledged line): their material is missing from the "
            "deposition below; the record lists them under <code>lost_in_reset</code>.")


def _html(result: DemoResult, figure: bool) -> str:
    e = html.escape
    s = result.stream
    volume = bool(result.ranking) and "lost_volume" in result.ranking[0]
    key, unit = ("lost_volume", "mm³") if volume else ("lost_area", "mm²")
    frac = "lost_volume_fraction" if volume else "lost_fraction"
    rank_head = "".join(f"<th>{e(h)}</th>" for h in (
        "rank", "nozzle", f"lost {unit}", "lost %", f"bounds {unit}",
        *(("lost area mm² (Σ layers)", "bounds mm² (Σ layers)") if volume else ())))
    rank_rows = "".join(
        f"<tr><td>{r['rank']}</td><td>{e(r['nozzle'])}</td><td>{r[key]:.4g}</td>"
        f"<td>{100 * r[frac]:.2f}</td><td>[{r[key + '_bounds'][0]:.4g}, "
        f"{r[key + '_bounds'][1]:.4g}]</td>"
        + (f"<td>{r['lost_area']:.4g}</td><td>[{r['lost_area_bounds'][0]:.4g}, "
           f"{r['lost_area_bounds'][1]:.4g}]</td>" if volume else "")
        + "</tr>" for r in result.ranking)
    what = ("each layer's lost area G \\ S times its height, summed; bounds: its certified "
            "interval" if volume else "the lost area G \\ S, summed over the layers; bounds: "
            "its certified interval")
    layer_head = "".join(f"<th>{e(name)} ({e(u)})</th>" for name, u in LAYER_COLUMNS)
    layer_rows = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in _layer_cells(r)) + "</tr>"
                         for r in result.layers)
    img = ('<p><img src="layers.png" alt="prediction per nozzle and deposition, per layer">'
           '</p>') if figure else (
        "<p>(no figure: matplotlib is not installed — pip install 'printability[report]')</p>")
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>printability demo</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:.2em .6em;text-align:right}}
img{{max-width:100%}}
</style></head><body>
<h1>printability demo: {e(result.nozzle)} on {e(result.machine)}</h1>
<h2>1–2. Nozzle ranking (lost {'volume' if volume else 'area'} over all layers)</h2>
<table><tr>{rank_head}</tr>{rank_rows}</table>
<p>Lost: {e(what)}. The figure below shows each nozzle's prediction.</p>
<h2>3. G-code</h2><p>{result.gcode_lines} commands with the rotary axis:
<a href="part.gcode">part.gcode</a>. {' '.join(e(n) for n in result.notes)}</p>
<h2>4. Streamed to the simulator</h2>
<p>{s.acknowledged} of {s.total} commands acknowledged ({e(s.mode)}), {s.resends} resends
(ratio {100 * s.resend_ratio:.2f} %), {s.timeouts} timeouts, {s.reconnects} reconnects.
The simulator executed exactly the file: <b>{'yes' if result.log_matches else 'NO'}</b>.
{_lost_note(result)}
Transcript: <a href="serial.log">serial.log</a>; record: <a href="record.json">record.json</a>.</p>
<h2>5. Target, prediction and deposition per layer</h2>
<table><tr>{layer_head}</tr>{layer_rows}</table>
<p>MMC violations reported by the simulator: {result.violations}.</p>
{img}
</body></html>
"""
