"""What the OctoPrint plugin does, without OctoPrint: its settings checked by printability's
own parsers and registries, a rewrite run exactly as ``printability postprocess`` runs it, the
summary of a rewrite, the drawing of the nozzle and the rotary-axis check on connect.

Nothing here imports OctoPrint (the plugin's ``__init__`` is the only module that does), so
what OctoPrint's 2.0 line changes stays in one place. printability itself is imported where
it is used: OctoPrint starts without paying for numpy, shapely and numba.
"""

from __future__ import annotations

import dataclasses
import html
import math
import os
from collections.abc import Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from gcode.printtime import format_duration
from printability.base.errors import PrintabilityError
from printability.base.options import FLAVORS, Registry

__all__ = [
    "DEFAULTS",
    "FLAVOR_AUTO",
    "UPLOAD_MODES",
    "FirmwareReport",
    "PrintabilityError",
    "axis_problem",
    "check_setting",
    "check_settings",
    "cli_arguments",
    "flavor_choices",
    "is_rotary_output",
    "machine_choices",
    "nozzle_facts",
    "nozzle_svg",
    "one_paragraph",
    "options_for",
    "output_name",
    "rewrite_file",
    "rotary_letter",
    "summary_html",
    "summary_of",
    "write_report",
]

UPLOAD_MODES = Registry("upload mode", (
    ("auto", "rewrite every G-code file uploaded to OctoPrint, into NAME.rotary.gcode beside it"),
    ("request", "rewrite a file when asked, from the plugin's tab"),
    ("never", "never rewrite (the settings, the drawing and the connect check stay)"),
))
"""What the plugin does with uploads (the settings page lists these)."""

FLAVOR_AUTO = "auto"
"""The flavor setting that adds nothing: the machine profile's flavor, else the slicer's own
``;FLAVOR`` comment, else Marlin (what ``printability postprocess`` does)."""

DEFAULTS: dict[str, Any] = {
    # "": not set yet; nothing is rewritten until the owner names the nozzle installed
    "nozzle": "",
    "machine": "ttr",
    "uploads": "auto",
    "flavor": FLAVOR_AUTO,
}

SUFFIX = ".rotary"
"""The rewritten file of NAME.gcode is NAME.rotary.gcode, in the same folder."""


# ----------------------------------------------------------------- settings


def check_setting(key: str, value: Any, *, base_dir: str | os.PathLike[str] | None = None
                  ) -> str:
    """The setting ``key`` as stored, or the one-paragraph reason it is refused.

    The nozzle and the machine are parsed by printability's own parsers
    (:func:`printability.model.nozzle.parse_nozzle`,
    :func:`printability.model.machine.parse_machine`),
    so a SPEC is refused with the message the CLI gives; ``base_dir`` is where a relative
    ``polygon:FILE.svg`` is looked for.

    Raises
    ------
    PrintabilityError
        (``InputError``, ``UnknownOptionError``, ...) with the registry's message.
    """
    if key == "nozzle":
        if value is None or (isinstance(value, str) and not value.strip()):
            return ""
        from printability.model.nozzle import parse_nozzle

        return parse_nozzle(value, base_dir=base_dir).spec
    if key == "machine":
        from printability.model.machine import parse_machine

        # stored as typed (a built-in profile by its name, a TOML file by its name in the
        # plugin's data folder), once it parses
        spec = value.strip() if isinstance(value, str) else value
        parse_machine(_machine_path(spec, base_dir))
        return spec
    if key == "uploads":
        return UPLOAD_MODES.check(value)
    if key == "flavor":
        if isinstance(value, str) and value.strip().lower() == FLAVOR_AUTO:
            return FLAVOR_AUTO
        return FLAVORS.check(value)
    raise KeyError(key)


def _machine_path(spec: Any, base_dir: str | os.PathLike[str] | None) -> Any:
    """A machine SPEC with a TOML file named without a folder looked for in ``base_dir``
    (the plugin's data folder)."""
    if isinstance(spec, str) and spec.strip().lower().endswith(".toml") \
            and base_dir is not None and not os.path.isabs(spec.strip()) \
            and os.sep not in spec.strip():
        return os.path.join(os.fspath(base_dir), spec.strip())
    return spec.strip() if isinstance(spec, str) else spec


def check_settings(data: Mapping[str, Any], *, base_dir: str | os.PathLike[str] | None = None
                   ) -> tuple[dict[str, str], dict[str, str]]:
    """Split settings a client sent into those accepted (as stored) and those refused (the
    reason, one paragraph, by key). Keys this plugin does not know are left out of both."""
    accepted: dict[str, str] = {}
    refused: dict[str, str] = {}
    for key in DEFAULTS:
        if key not in data:
            continue
        try:
            accepted[key] = check_setting(key, data[key], base_dir=base_dir)
        except PrintabilityError as exc:
            refused[key] = str(exc)
    return accepted, refused


def flavor_choices() -> list[dict[str, str]]:
    """The flavor setting's choices for the settings page: ``auto`` and the registry's."""
    return [{"value": FLAVOR_AUTO, "text": "auto: the machine profile's, else the slicer's "
             ";FLAVOR comment, else marlin"}] + \
        [{"value": k, "text": f"{k}: {v}"} for k, v in FLAVORS.items()]


def machine_choices() -> list[str]:
    """Machine SPECs to offer (the built-in kinds and profiles; any other SPEC or a TOML
    file is accepted too)."""
    from printability.model.machine import builtin_profiles

    return ["ttr", "ttr:min=-90,max=90", "xy",
            *(name for name in builtin_profiles() if name not in ("ttr", "xy"))]


def options_for(settings: Mapping[str, Any], *, base_dir: str | os.PathLike[str] | None = None):
    """The :class:`~printability.postprocess.PostprocessOptions` of the settings: those of
    ``printability postprocess --nozzle N --machine M`` (its defaults otherwise), the flavor
    set on the machine when it is not ``auto``."""
    from printability.model.machine import parse_machine
    from printability.postprocess import PostprocessOptions

    nozzle = check_setting("nozzle", settings.get("nozzle"), base_dir=base_dir) or None
    machine_spec = _machine_path(settings.get("machine") or DEFAULTS["machine"], base_dir)
    flavor = check_setting("flavor", settings.get("flavor") or FLAVOR_AUTO)
    machine: Any = machine_spec
    if flavor != FLAVOR_AUTO:
        machine = dataclasses.replace(parse_machine(machine_spec), flavor=flavor)
    return PostprocessOptions(nozzle=nozzle, machine=machine)


def cli_arguments(settings: Mapping[str, Any]) -> list[str] | None:
    """The ``printability postprocess`` options that write the same bytes (None when there are
    none: a flavor other than ``auto`` is set on the machine, which the CLI takes only from a
    machine profile's ``[firmware] flavor``)."""
    if (settings.get("flavor") or FLAVOR_AUTO) != FLAVOR_AUTO:
        return None
    args = []
    if settings.get("nozzle"):
        args += ["--nozzle", str(settings["nozzle"])]
    args += ["--machine", str(settings.get("machine") or DEFAULTS["machine"])]
    return args


# ----------------------------------------------------------------- files


def output_name(name: str) -> str:
    """``part.gcode`` → ``part.rotary.gcode`` (the extension kept, whatever it is)."""
    stem, dot, ext = name.rpartition(".")
    if not dot or not stem:
        return name + SUFFIX
    return f"{stem}{SUFFIX}.{ext}"


def is_rotary_output(name: str) -> bool:
    """A name this plugin writes (``*.rotary.<ext>``): never rewritten again."""
    stem, dot, _ = name.rpartition(".")
    return name.endswith(SUFFIX) or (bool(dot) and stem.endswith(SUFFIX))


def rewrite_file(source: str | os.PathLike[str], output: str | os.PathLike[str],
                 settings: Mapping[str, Any], *,
                 base_dir: str | os.PathLike[str] | None = None):
    """Rewrite ``source`` into ``output`` with the function ``printability postprocess``
    calls (:func:`printability.postprocess.postprocess_file`), so that ``output`` holds the
    bytes the CLI writes with :func:`cli_arguments`. OctoPrint is not a slicer: the
    ``SLIC3R_*`` settings a slicer exports to its scripts do not apply (an empty environment
    is given).

    Returns
    -------
    PostprocessResult
        ``already_processed`` is True (and nothing is written) for a file printability
        already rewrote.

    Raises
    ------
    PrintabilityError
        With the one-paragraph message the CLI prints; ``source`` is never changed.
    """
    from printability.postprocess import postprocess_file

    opts = options_for(settings, base_dir=base_dir)
    res = postprocess_file(source, options=opts, output=output, env={})
    if res.already_processed:
        # postprocess_file writes the input unchanged to another output: not a new file here
        try:
            os.unlink(output)
        except OSError:
            pass
    return res


def _finite(x: float | None) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def summary_of(res, *, source: str, output: str, settings: Mapping[str, Any]) -> dict[str, Any]:
    """A rewrite's summary as JSON: per layer the target and lost areas (mm²) and what could
    not be printed, the totals, and the print time on the firmware's planner before and
    after (seconds; ``None`` when not estimated)."""
    layers = [{
        "index": r.index, "z": r.z, "target_area": r.target_area, "lost_area": r.dropped_area,
        "moves": r.moves, "turned": r.turned, "split_moves": r.split_moves,
        "dropped_moves": r.dropped_moves, "dropped_length": r.dropped_length,
        "printed_length": r.printed_length,
    } for r in res.layers]
    target = sum(r.target_area for r in res.layers)
    lost = sum(r.dropped_area for r in res.layers)
    t_in, t_out = _finite(res.print_time_in), _finite(res.print_time_out)
    return {
        "source": source,
        "output": output,
        "nozzle": res.nozzle,
        "machine": res.machine,
        "flavor": settings.get("flavor") or FLAVOR_AUTO,
        "cli": cli_arguments(settings),
        "lines_in": res.lines_in,
        "lines_out": res.lines_out,
        "changed_lines": res.changed_lines,
        "inserted_lines": res.inserted_lines,
        "rotary_words": res.rotary_words,
        "split_moves": res.split_moves,
        "dropped_moves": res.dropped_moves,
        "dropped_length": res.dropped_length,
        "target_area": target,
        "lost_area": lost,
        "lost_share": lost / target if target > 0 else 0.0,
        "layers_losing": sum(1 for r in res.layers if r.dropped_moves or r.split_moves),
        "layers": layers,
        "print_time_in": t_in,
        "print_time_out": t_out,
        "print_time_ratio": t_out / t_in if t_in and t_out is not None else None,
        "elapsed": res.elapsed,
        "notes": list(res.notes),
    }


def write_report(source: str | os.PathLike[str], out_dir: str | os.PathLike[str],
                 settings: Mapping[str, Any], *, layers: int = 3,
                 base_dir: str | os.PathLike[str] | None = None) -> Path:
    """The HTML report of ``printability analyze`` for the slicer's file (the installed nozzle
    on the machine, ``layers`` layers spread over the part, one process), in ``out_dir``;
    returns its ``index.html``."""
    from printability.analysis import analyze, select_layers
    from printability.analysis.report import write_report as _write
    from printability.settings import Settings
    from printability.sources import load_layers

    opts = options_for(settings, base_dir=base_dir)
    stack = load_layers(os.fspath(source))
    n = len(stack)
    if n > layers:
        picks = sorted({round(i * (n - 1) / max(layers - 1, 1)) for i in range(layers)})
        stack = select_layers(stack, ",".join(str(i) for i in picks))
    nozzle = opts.nozzle or "circle:d=0.4"
    # one process: OctoPrint's server is threaded, and a fork of it is not to be trusted
    analysis = analyze(stack, [nozzle], opts.machine, settings=Settings(workers=1, progress=False))
    return _write(analysis, out_dir)


def summary_html(summary: Mapping[str, Any]) -> str:
    """The summary as a page of its own (linked from the plugin's tab)."""
    e = html.escape

    def t(x: float | None) -> str:
        return "not estimated" if x is None else format_duration(x)

    rows = "".join(
        f"<tr><td>{r['index']}</td><td>{r['z']:.3f}</td><td>{r['target_area']:.3f}</td>"
        f"<td>{r['lost_area']:.4f}</td><td>{r['dropped_moves']}</td>"
        f"<td>{r['dropped_length']:.3f}</td><td>{r['split_moves']}</td></tr>"
        for r in summary["layers"])
    ratio = summary.get("print_time_ratio")
    cli = summary.get("cli")
    same = ("<p>The same file: <code>printability postprocess FILE -o OUT "
            + e(" ".join(cli)) + "</code></p>") if cli else ""
    notes = "".join(f"<li>{e(n)}</li>" for n in summary.get("notes", ()))
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>printability: {e(summary['output'])}</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:60em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}
</style></head><body>
<h1>{e(summary['output'])}</h1>
<p>Rewritten from <b>{e(summary['source'])}</b> for the nozzle <code>{e(summary['nozzle'])}</code>
on the machine <code>{e(summary['machine'])}</code> (flavor {e(str(summary['flavor']))}).</p>
<ul>
<li>{summary['lines_in']} lines in, {summary['lines_out']} out; {summary['rotary_words']} rotary
words</li>
<li>not printable: {summary['lost_area']:.3f} mm² of {summary['target_area']:.1f} mm²
({100 * summary['lost_share']:.2f} %); {summary['dropped_moves']} moves dropped,
{summary['split_moves']} shortened, {summary['dropped_length']:.2f} mm of path;
{summary['layers_losing']} of {len(summary['layers'])} layers lose something</li>
<li>print time on the firmware's planner (estimated): {t(summary['print_time_in'])} as sliced,
{t(summary['print_time_out'])} rewritten{f" ({ratio:.2f}x)" if ratio else ""}</li>
</ul>{same}
<h2>Per layer</h2>
<table><tr><th>layer</th><th>z mm</th><th>target mm²</th><th>lost mm²</th>
<th>dropped moves</th><th>dropped mm</th><th>shortened moves</th></tr>{rows}</table>
<h2>Notes</h2><ul>{notes}</ul>
</body></html>
"""


# ----------------------------------------------------------------- the drawing


def nozzle_facts(spec: str, *, base_dir: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """What the settings page shows beside the drawing (mm, mm²)."""
    from printability.model.nozzle import parse_nozzle

    n = parse_nozzle(spec, base_dir=base_dir)
    return {"spec": n.spec, "kind": n.kind, "orifices": len(n.footprints), "area": n.area,
            "min_width": n.min_width, "max_width": n.max_width, "radius": n.radius,
            "turns": not n.is_round}


def nozzle_svg(spec: str, *, base_dir: str | os.PathLike[str] | None = None,
               size: int = 160) -> str:
    """An SVG drawing of the nozzle's outline at angle 0 in the nozzle frame (x to the right,
    y up), the rotation axis marked with a cross and a 1 mm scale bar."""
    from shapely.geometry import MultiPolygon

    from printability.model.nozzle import parse_nozzle

    n = parse_nozzle(spec, base_dir=base_dir)
    outline = n.outline(0.0)
    polys = list(outline.geoms) if isinstance(outline, MultiPolygon) else [outline]
    x0, y0, x1, y1 = outline.bounds
    x0, y0, x1, y1 = min(x0, 0.0), min(y0, 0.0), max(x1, 0.0), max(y1, 0.0)
    span = max(x1 - x0, y1 - y0, 1e-3)
    pad = 0.15 * span
    x0, y0, x1, y1 = x0 - pad, y0 - pad, x1 + pad, y1 + pad
    w, h = x1 - x0, y1 - y0
    stroke = span / 150
    paths = []
    for p in polys:
        pts = " ".join(f"{x:.5f},{-y:.5f}" for x, y in p.exterior.coords)
        paths.append(f'<polygon points="{pts}" fill="#4c9be8" fill-opacity="0.55" '
                     f'stroke="#1d5fa8" stroke-width="{stroke:.5f}"/>')
    c = 0.06 * span
    cross = (f'<path d="M{-c:.5f},0 H{c:.5f} M0,{-c:.5f} V{c:.5f}" stroke="#c0392b" '
             f'stroke-width="{stroke:.5f}"/>')
    bar = min(1.0, 10 ** math.floor(math.log10(span)))
    by = -y0 - 0.4 * pad
    scale = (f'<path d="M{x0 + 0.4 * pad:.5f},{by:.5f} h{bar:.5f}" stroke="#333" '
             f'stroke-width="{2 * stroke:.5f}"/>'
             f'<text x="{x0 + 0.4 * pad:.5f}" y="{by - 0.3 * pad:.5f}" '
             f'font-size="{0.09 * h:.5f}" fill="#333">{bar:g} mm</text>')
    title = html.escape(f"nozzle {n.spec}: outline at angle 0 (x right, y up); the cross is "
                        "the rotation axis")
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{size}" '
            f'height="{round(size * h / w)}" viewBox="{x0:.5f} {-y1:.5f} {w:.5f} {h:.5f}">'
            f"<title>{title}</title>{''.join(paths)}{cross}{scale}</svg>")


# ----------------------------------------------------------------- the connect check


@dataclasses.dataclass
class FirmwareReport:
    """What the printer said about itself since the last connect: the M115 reply lines
    (``FIRMWARE_NAME:…``, ``Cap:…``) and the last M114 position report."""

    lines: list[str] = dataclasses.field(default_factory=list)
    position: str | None = None

    def feed(self, line: str) -> str | None:
        """Keep a received line if it is part of M115's or M114's reply; returns ``"m115"`` or
        ``"m114"`` for such a line (None otherwise)."""
        from machine_io.protocol import parse_position

        s = line.strip()
        if s.startswith(("FIRMWARE_NAME:", "Cap:")):
            if s.startswith("FIRMWARE_NAME:"):
                self.lines = [s]
            else:
                self.lines.append(s)
            return "m115"
        if "Count" in s and parse_position(s) is not None:
            self.position = s
            return "m114"
        return None


def axis_problem(report: FirmwareReport, letter: str, port: str, source: str) -> str | None:
    """The message ``printability stream`` gives when the firmware does not report the rotary
    axis ``letter`` (its own check, :meth:`machine_io.streaming.StreamingMixin._check_axes`,
    run on what OctoPrint's connection received), or None when the axis is there."""
    from machine_io.protocol import parse_firmware_info, parse_position
    from machine_io.streaming import StreamingMixin
    from printability.base.errors import PrinterError

    info = parse_firmware_info(report.lines,
                               parse_position(report.position) if report.position else None)
    host = SimpleNamespace(config=SimpleNamespace(check_axes=True), firmware=info,
                           port_name=port)
    program = SimpleNamespace(rotary_axes=frozenset({letter.upper()}), source=source)
    try:
        StreamingMixin._check_axes(host, program)  # type: ignore[arg-type]
    except PrinterError as exc:
        return str(exc)
    return None


def rotary_letter(settings: Mapping[str, Any], *, base_dir: str | os.PathLike[str] | None = None
                  ) -> str | None:
    """The rotary axis the rewritten files drive (None: the machine turns no nozzle)."""
    from printability.model.machine import parse_machine

    m = parse_machine(_machine_path(settings.get("machine") or DEFAULTS["machine"], base_dir))
    return m.rotary_letter if m.has_rotary else None


def one_paragraph(exc: BaseException, *, name: str,
                  disk_path: str | os.PathLike[str] | None = None) -> str:
    """What a user is told when a rewrite fails, in one paragraph.

    printability's own message for its errors (the file's path on disk, ``disk_path``, shown
    as its name in OctoPrint's files), the kind of failure for anything else (the traceback
    goes to octoprint.log); it ends by saying the upload is unchanged.
    """
    if isinstance(exc, PrintabilityError):
        text = str(exc)
    else:
        text = (f"printability could not rewrite {name}: an internal error "
                f"({type(exc).__name__}: {exc}); the details are in octoprint.log")
    if disk_path is not None and os.fspath(disk_path):
        text = text.replace(os.fspath(disk_path), name)
    text = " ".join(text.split())
    if "unchanged" not in text and "untouched" not in text:
        text = text.rstrip(".") + f". {name} is unchanged."
    return text
