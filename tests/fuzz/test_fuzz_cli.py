"""The real CLI on mutants of the shared samples, every input kind (issue #24, item 5).

Each G-code sample's first 2000 lines go through ``printability postprocess -o OUT``; each
shared SVG through ``printability analyze`` and, as the nozzle of a square part, through
``--nozzle polygon:FILE``; two GeoJSON maps, two slice-outline files, an STL mesh and a WKT
drawing through ``printability analyze``. Every run must end clean (exit 0) or with one
paragraph ``printability: error:`` and exit 1: no traceback, no hang, no crash; and its peak
memory must stay within the reader's guard: that many bytes per byte of the mutant over the
peak of an unmutated run of the same kind (:meth:`_fuzz.Tally.over_memory`). The counts
(tried / clean / error / traceback / hang / other) and the largest peak are printed. The
mutants are seeded (see ``_fuzz.py``; ``python tests/fuzz/_fuzz.py --count 50`` explores
more); the default run tries a few per sample, the ``slow`` one many.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from _fuzz import (
    NOZZLE,
    Tally,
    analyze_jobs,
    gcode_jobs,
    head_lines,
    report,
    run_all,
    run_cli,
    square_part,
    svg_jobs,
)

SEED = 24  # the number: a red run names a regression, not a new draw
HANG = 60.0  # seconds after which a run counts as a hang (a normal one takes 1–3 s)

# The guards' estimates, bytes of memory per byte of input: postprocess when it plans every
# move (printability.postprocess.memory.BYTES_PER_BYTE_PLANNED), the SVG, map and slice readers
# (their _BYTES_PER_INPUT_BYTE), a mesh (its triangles: about 50 bytes of file each, 30 kB
# of work each at the most a slicing of a few layers takes; bounded here by the SVG's).
PER_BYTE = {"gcode": 100.0, "svg": 120.0, "geojson": 60.0, "wkt": 60.0, "slices": 120.0,
            "stl": 120.0}

# A drawing in WKT (no shared sample has one): a plate with a hole and a slot.
WKT = ("POLYGON ((0 0, 30 0, 30 20, 0 20, 0 0), (5 5, 12 5, 12 12, 5 12, 5 5))\n"
       "POLYGON ((40 0, 41.2 0, 41.2 20, 40 20, 40 0))\n")


def _samples(shared_data: Path, folder: Path) -> dict[str, list[Path]]:
    """The samples of each input kind: the shared ones, and a WKT drawing written here."""
    wkt = folder / "plate.wkt"
    wkt.write_text(WKT)
    slices = sorted((shared_data / "slices").glob("*.txt"), key=lambda p: p.stat().st_size)
    return {
        "gcode": sorted((shared_data / "gcode").glob("*.gcode")),
        "svg": sorted((shared_data / "svg").glob("*.svg")),
        "geojson": [shared_data / "japan_110m.geojson", shared_data / "japan_50m.geojson"],
        "slices": [slices[len(slices) // 2], slices[-1]],
        "stl": [shared_data / "stl" / "CalibrationCube.stl"],
        "wkt": [wkt],
    }


#: The options each kind of analysis runs with (a map needs a print size; a mesh, layers).
EXTRA = {"geojson": ("--fit", "50"), "stl": ("--layer-height", "5"), "slices": (),
         "wkt": ()}


@pytest.fixture(scope="module")
def warm(tmp_path_factory, shared_data):
    """One unmutated run of each kind first, one at a time: a kernel cache that is cold
    (a new checkout, an edited kernel) compiles here, not inside a timed mutant; and the
    peak memory of each kind's run, what the mutants' are measured against."""
    folder = tmp_path_factory.mktemp("fuzz-warm")
    samples = _samples(shared_data, folder)
    gcode = folder / "head.gcode"
    gcode.write_bytes(head_lines(samples["gcode"][0]))
    svg = samples["svg"][0]
    part = square_part(folder)
    runs = {"gcode": ["postprocess", str(gcode), "-o", str(folder / "out.gcode"), "--nozzle",
                      NOZZLE],
            "svg": ["analyze", str(svg), "--no-progress", "-j", "1"],
            "nozzle": ["analyze", str(part), "--nozzle", f"polygon:{svg}", "--no-progress",
                       "-j", "1"]}
    for kind, extra in EXTRA.items():
        runs[kind] = ["analyze", str(samples[kind][-1]), "--no-progress", "-j", "1", *extra]
    reference = {}
    for kind, args in runs.items():
        outcome = run_cli(args, timeout=900)
        assert outcome.kind == "clean", (kind, outcome.stderr)
        reference[kind] = outcome.peak
    reference["svg"] = max(reference["svg"], reference.pop("nozzle"))
    return {"samples": samples, "reference": reference}


def _fuzz(name: str, jobs: list[list[str]], capsys, *, reference: int, per_byte: float
          ) -> Tally:
    tally = run_all(jobs, timeout=HANG, workers=min(2, os.cpu_count() or 1))
    text = report(tally, name)
    heavy = tally.over_memory(reference, per_byte)
    text += "".join(f"\n  memory {o.peak / 2**20:.0f} MiB for {o.size / 1e3:.0f} kB (over "
                    f"{1.25 * reference / 2**20:.0f} MiB + {per_byte:g} per byte): "
                    f"printability {' '.join(o.args)}" for o in heavy)
    with capsys.disabled():
        print("\n" + text)
    assert not tally.failures() and not heavy, text
    assert reference > 0 and all(o.peak > 0 for o in tally.outcomes), "no memory measured"
    return tally


def test_postprocess_on_mutated_gcode(warm, tmp_path, capsys):
    _fuzz("gcode postprocess", gcode_jobs(warm["samples"]["gcode"], SEED, 3, tmp_path), capsys,
          reference=warm["reference"]["gcode"], per_byte=PER_BYTE["gcode"])


def test_analyze_and_nozzle_on_mutated_svg(warm, tmp_path, capsys):
    jobs = svg_jobs(warm["samples"]["svg"], SEED, 4, tmp_path, square_part(tmp_path))
    _fuzz("svg analyze / nozzle", jobs, capsys, reference=warm["reference"]["svg"],
          per_byte=PER_BYTE["svg"])


@pytest.mark.parametrize("kind", list(EXTRA))
def test_analyze_on_mutated_maps_slices_meshes_and_drawings(warm, tmp_path, capsys, kind):
    jobs = analyze_jobs(warm["samples"][kind], SEED, 2, tmp_path, EXTRA[kind])
    _fuzz(f"{kind} analyze", jobs, capsys, reference=warm["reference"][kind],
          per_byte=PER_BYTE[kind])


@pytest.mark.slow
def test_postprocess_on_many_mutants(warm, tmp_path, capsys):
    _fuzz("gcode postprocess (slow)", gcode_jobs(warm["samples"]["gcode"], SEED + 1, 25,
                                                 tmp_path), capsys,
          reference=warm["reference"]["gcode"], per_byte=PER_BYTE["gcode"])


@pytest.mark.slow
def test_analyze_and_nozzle_on_many_mutants(warm, tmp_path, capsys):
    jobs = svg_jobs(warm["samples"]["svg"], SEED + 1, 25, tmp_path, square_part(tmp_path))
    _fuzz("svg analyze / nozzle (slow)", jobs, capsys, reference=warm["reference"]["svg"],
          per_byte=PER_BYTE["svg"])


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(EXTRA))
def test_analyze_on_many_mutated_inputs(warm, tmp_path, capsys, kind):
    jobs = analyze_jobs(warm["samples"][kind], SEED + 1, 25, tmp_path, EXTRA[kind])
    _fuzz(f"{kind} analyze (slow)", jobs, capsys, reference=warm["reference"][kind],
          per_byte=PER_BYTE[kind])
