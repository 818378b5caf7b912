"""Reader semantics: layers per dialect, modal state, arcs, errors, pygcode cross-check."""

from __future__ import annotations

import math
import re

import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given, settings

from gcode import (
    MF_E_RELATIVE,
    MF_INCH,
    MF_RETRACTED,
    arc_chord_count,
    arc_length,
    linearise,
    parse_gcode,
    read_gcode,
)
from printability.errors import FileFormatError, PrintabilityOSError
from printability.settings import Settings

# (file, dialect, layers, first z, last z, height, layer count the file itself states)
LAYERS = [
    ("bambustudio_1.10_klipper_arcs.gcode", "bambu", 25, 0.2, 5.0, 0.2,
     rb"; total layer number: (\d+)"),
    ("cura_5.9.1_marlin.gcode", "cura", 25, 0.2, 5.0, 0.2, rb";LAYER_COUNT:(\d+)"),
    ("orcaslicer_2.3.0b2_klipper_arcs.gcode", "prusa", 190, 0.2, 38.0, 0.2,
     rb"; total layer number: (\d+)"),
    ("prusaslicer_2.7.4_marlin2_arcs.gcode", "prusa", 139, 0.3, 41.7, 0.3, None),
    ("prusaslicer_2.7.4_spiral_vase.gcode", "prusa", 334, 0.3, 99.9, 0.3, None),
    ("slic3rpe_1.33_arcwelder_benchy.gcode", "zmoves", 240, 0.2, 48.0, 0.2, None),
]


@pytest.fixture(scope="module")
def gfiles(shared_data):
    return {name: read_gcode(shared_data / "gcode" / name) for name, *_ in LAYERS}


@pytest.mark.parametrize(("name", "dialect", "n", "z0", "z1", "h", "stated"), LAYERS)
def test_layers_of_each_dialect(gfiles, name, dialect, n, z0, z1, h, stated):
    g = gfiles[name]
    L = g.layers
    assert g.dialect == dialect
    assert len(L) == n
    assert L["z"][0] == pytest.approx(z0) and L["z"][-1] == pytest.approx(z1)
    assert np.all(np.diff(L["z"]) >= -1e-9)
    assert np.all(L["n_extrusions"] > 0)
    assert np.median(L["height"]) == pytest.approx(h, abs=1e-4)
    if stated is not None:  # the slicer's own count in its header
        assert int(re.search(stated, g.data).group(1)) == n
    # every extrusion after the first layer marker is in a layer, in order
    ext = g.moves[g.moves["is_extrusion"]]
    assert np.all(np.diff(g.moves["layer"]) >= 0)
    assert (ext["layer"] >= 0).mean() > 0.95


def _distinct_extrusion_z(data: bytes) -> int:
    """Independent count: Z values at which E advances (absolute E, G92 resets), by regex."""
    z = e = 0.0
    zs = set()
    for line in data.decode().splitlines():
        code = line.split(";")[0].split()
        if not code:
            continue
        words = {w[0]: float(w[1:]) for w in code[1:] if len(w) > 1}
        if code[0] == "G92" and "E" in words:
            e = words["E"]
        elif code[0] in ("G0", "G1", "G2", "G3"):
            z = words.get("Z", z)
            if "E" in words:
                if words["E"] > e + 1e-9 and ({"X", "Y"} & words.keys()):
                    zs.add(round(z, 4))
                e = words["E"]
    return len(zs)


def test_benchy_layers_from_z_match_an_independent_count(gfiles):
    g = gfiles["slic3rpe_1.33_arcwelder_benchy.gcode"]
    assert g.arcwelder and g.flavor == "reprap"
    assert _distinct_extrusion_z(g.data) == len(g.layers) == 240
    assert np.allclose(np.diff(g.layers["z"]), 0.2)


@pytest.mark.parametrize(("name", "n_extra"), [
    ("bambustudio_1.10_klipper_arcs.gcode", 0),
    ("cura_5.9.1_marlin.gcode", 0),
    ("orcaslicer_2.3.0b2_klipper_arcs.gcode", 0),
    ("prusaslicer_2.7.4_marlin2_arcs.gcode", 1),  # the purge line at Z 0.28 is a layer of its own
])
def test_layers_from_z_agree_with_markers(gfiles, name, n_extra):
    g = gfiles[name]
    stripped = re.sub(rb"(?m)^(;LAYER_CHANGE|; CHANGE_LAYER|;LAYER:-?\d+)[ \t]*$", b";", g.data)
    gz = parse_gcode(stripped)
    assert gz.dialect == "zmoves"
    assert len(gz.layers) == len(g.layers) + n_extra
    assert np.allclose(gz.layers["z"][n_extra:], g.layers["z"])


def test_spiral_vase_layers_from_z(gfiles):
    g = gfiles["prusaslicer_2.7.4_spiral_vase.gcode"]
    # Z rises while extruding inside a marker layer
    m = g.moves[g.moves["is_extrusion"] & (g.moves["layer"] == 10)]
    assert m["z1"].max() - m["z0"].min() == pytest.approx(0.3, abs=0.01)
    stripped = re.sub(rb"(?m)^;LAYER_CHANGE[ \t]*$", b";", g.data)
    gz = parse_gcode(stripped)
    # purge line + 332 distinct layer tops; the marker file ends with two layers at 99.9
    assert len(gz.layers) == 1 + len(np.unique(g.layers["z"]))
    assert np.allclose(gz.layers["z"][1:], np.unique(g.layers["z"]))


def test_features_and_widths(gfiles):
    g = gfiles["prusaslicer_2.7.4_marlin2_arcs.gcode"]
    assert "External perimeter" in g.features
    cats = g.feature_category_of_moves()
    ext = g.moves["is_extrusion"]
    assert set(cats[ext]) >= {"outer_wall", "inner_wall", "sparse_infill", "skirt"}
    assert np.isfinite(g.moves["width"][ext & (cats != "custom")]).all()
    b = gfiles["bambustudio_1.10_klipper_arcs.gcode"]
    w = b.moves["width"][b.moves["is_extrusion"]]
    assert np.nanmin(w) > 0.05 and np.nanmax(w) < 1.0
    c = gfiles["cura_5.9.1_marlin.gcode"]
    assert np.isnan(c.moves["width"]).all()
    assert set(c.feature_categories) == {"skirt", "inner_wall", "outer_wall", "solid_infill",
                                         "sparse_infill"}
    o = gfiles["orcaslicer_2.3.0b2_klipper_arcs.gcode"]
    assert o.moves["wipe"].any()
    assert not (o.moves["wipe"] & o.moves["is_extrusion"]).any()


def test_total_filament_matches_slicer_report(gfiles):
    # The filament the slicer says it uses is the E of the extruding moves.
    c = gfiles["cura_5.9.1_marlin.gcode"]
    used = float(re.search(rb";Filament used: ([\d.]+)m", c.data).group(1)) * 1000
    assert c.moves["e"][c.moves["is_extrusion"]].sum() == pytest.approx(used, abs=0.005)
    p = gfiles["prusaslicer_2.7.4_marlin2_arcs.gcode"]
    used = float(re.search(rb"; filament used \[mm\] = ([\d.]+)", p.data).group(1))
    assert p.moves["e"][p.moves["is_extrusion"]].sum() == pytest.approx(used, abs=0.005)


# ---------- modal state on synthetic files ----------


def moves_of(text: str, **kw):
    return parse_gcode(text.encode(), **kw).moves


def test_e_modes_give_the_same_deltas():
    absolute = moves_of("G90\nM82\nG92 E0\nG1 X0 Y0\nG1 X10 E1\nG1 X20 E3\nG92 E0\nG1 X30 E0.5\n")
    relative = moves_of("G90\nM83\nG1 X0 Y0\nG1 X10 E1\nG1 X20 E2\nG92 E0\nG1 X30 E0.5\n")
    assert absolute["e"].tolist() == relative["e"].tolist() == [0, 1, 2, 0.5]
    assert not (absolute["flags"] & MF_E_RELATIVE).any()
    assert (relative["flags"][1:] & MF_E_RELATIVE).all()


def test_g90_after_m83_depends_on_flavor():
    text = "M83\nG90\nG1 X0 Y0\nG1 X1 E1\nG1 X2 E1\n"
    # Marlin: G90 resets E to absolute, so the second E1 feeds nothing
    assert moves_of(text, flavor="marlin")["e"].tolist() == [0, 1, 0]
    # Klipper keeps M83
    assert moves_of(text, flavor="klipper")["e"].tolist() == [0, 1, 1]
    # the slicer's comment picks it when asked for auto
    assert moves_of(text + "; gcode_flavor = klipper\n")["e"].tolist() == [0, 1, 1]


def test_g91_relative_moves():
    m = moves_of("G90\nG1 X10 Y10 Z1\nG91\nG1 X1 Y-2 E0.5\nG1 Z0.2\nG90\nG1 X0\n")
    assert m[["x1", "y1", "z1"]].tolist() == [(10, 10, 1), (11, 8, 1), (11, 8, 1.2), (0, 8, 1.2)]
    assert m["e"].tolist() == [0, 0.5, 0, 0]


def test_g92_shifts_the_logical_frame():
    m = moves_of("G1 X10 Y10 Z0.2\nG92 X0 Y0\nG1 X5 Y5\nG92.1\nG1 X5\n")
    assert m[["x1", "y1"]].tolist() == [(10, 10), (15, 15), (5, 15)]


def test_unknown_start_position_is_nan_until_set():
    m = moves_of("G91\nG1 X1\nG90\nG1 X5 Y5\nG28 X\nG1 Y1\n")
    assert np.isnan(m["x1"][0])
    assert m[["x1", "y1"]].tolist()[1:] == [(5, 5), (0, 1)]
    assert not m["is_extrusion"].any()


def test_inches():
    m = moves_of("G20\nM83\nG1 X0 Y0 F60\nG1 X1 Y2 E0.1\nG21\nG1 X10\n")
    assert m["x1"].tolist() == [0, 25.4, 10] and m["y1"][1] == pytest.approx(50.8)
    assert m["e"][1] == pytest.approx(2.54) and m["feed"][0] == pytest.approx(1524)
    assert (m["flags"][:2] & MF_INCH).all() and not m["flags"][2] & MF_INCH


def test_firmware_retraction_and_tools():
    m = moves_of("T0\nM83\nG1 X0 Y0\nG10\nG1 X5\nG11\nT1\nG1 X6 E1\nG10 P1 S200\nG1 X7 E1\n")
    assert [bool(f & MF_RETRACTED) for f in m["flags"]] == [False, True, False, False]
    assert m["tool"].tolist() == [0, 0, 1, 1]


def test_valueless_words_do_not_move():
    m = moves_of("G1 X1 Y1\nM84 X Y E\nG1 Y2\n")
    assert m[["x1", "y1"]].tolist() == [(1, 1), (1, 2)]
    # on a move, a word without a number is refused (firmware disagree on it)
    with pytest.raises(FileFormatError, match="X without a number"):
        moves_of("G1 X1 Y1\nG1 X Y2\n")


def test_extrusion_needs_xy_motion():
    m = moves_of("M83\nG1 X0 Y0\nG1 E2\nG1 X1 E-1\nG1 X2 E0.1\nG1 Z1 E0.1\n")
    assert m["is_extrusion"].tolist() == [False, False, False, True, False]


# ---------- arcs ----------


def test_quarter_arcs_ij_and_r():
    g3 = moves_of("G1 X10 Y0\nG3 X0 Y10 I-10 J0\n")[1]
    assert (g3["cx"], g3["cy"]) == (0, 0) and g3["sweep"] == pytest.approx(math.pi / 2)
    g2 = moves_of("G1 X10 Y0\nG2 X0 Y10 I-10 J0\n")[1]
    assert g2["sweep"] == pytest.approx(-3 * math.pi / 2)
    # R > 0: the short way round; R < 0: the long way
    r_short = moves_of("G1 X10 Y0\nG3 X0 Y10 R10\n")[1]
    assert (r_short["cx"], r_short["cy"]) == pytest.approx((0, 0), abs=1e-12)
    assert r_short["sweep"] == pytest.approx(math.pi / 2)
    r_long = moves_of("G1 X10 Y0\nG3 X0 Y10 R-10\n")[1]
    assert (r_long["cx"], r_long["cy"]) == pytest.approx((10, 10))
    assert r_long["sweep"] == pytest.approx(3 * math.pi / 2)
    r_cw = moves_of("G1 X10 Y0\nG2 X0 Y10 R10\n")[1]
    assert (r_cw["cx"], r_cw["cy"]) == pytest.approx((10, 10))
    assert r_cw["sweep"] == pytest.approx(-math.pi / 2)


def test_full_circles_and_turns():
    full = moves_of("G1 X10 Y0 Z1\nG2 I-10 J0 Z2\nG3 I-10 J0 P1\n")
    assert full["sweep"][1] == pytest.approx(-2 * math.pi)
    assert full["sweep"][2] == pytest.approx(4 * math.pi)
    seg = linearise(full, 0.001)
    one = seg[seg["move"] == 1]
    assert (one["x1"][-1], one["y1"][-1], one["z1"][-1]) == (10, 0, 2)
    assert np.all(np.diff(one["z1"]) > 0)  # helical


@pytest.mark.parametrize("tol", [0.1, 0.01, 0.001])
@pytest.mark.parametrize(("r", "sweep_deg"), [(1.0, 90.0), (25.0, 200.0), (0.3, 360.0)])
def test_linearised_arc_exact(tol, r, sweep_deg):
    th = math.radians(sweep_deg)
    x0, y0 = 5.0 + r, 7.0
    x1, y1 = 5.0 + r * math.cos(th), 7.0 + r * math.sin(th)
    end = "" if sweep_deg == 360.0 else f"X{x1!r} Y{y1!r} "
    m = moves_of(f"M83\nG1 X{x0!r} Y{y0!r}\nG3 {end}I{-r!r} J0 E1\n")
    seg = linearise(m, tol)
    s = seg[seg["move"] == 1]
    n = int(arc_chord_count(np.array([r]), np.array([th]), tol)[0])
    assert len(s) == n
    # chords end on the circle, meet end to end, and start/end exactly at the move's ends
    for c in ("0", "1"):
        rr = np.hypot(s["x" + c] - 5.0, s["y" + c] - 7.0)
        assert np.allclose(rr, r, atol=1e-9)
    assert (s["x0"][0], s["y0"][0]) == (x0, y0)
    assert (s["x1"][-1], s["y1"][-1]) == (m["x1"][1], m["y1"][1])
    assert np.array_equal(s["x0"][1:], s["x1"][:-1])
    # sagitta within tolerance, and the chord length sum is the exact polygon's
    mid = np.hypot((s["x0"] + s["x1"]) / 2 - 5.0, (s["y0"] + s["y1"]) / 2 - 7.0)
    assert np.all(r - mid <= tol + 1e-12)
    length = np.hypot(s["x1"] - s["x0"], s["y1"] - s["y0"]).sum()
    assert length == pytest.approx(2 * n * r * math.sin(th / (2 * n)), rel=1e-9)
    assert arc_length(np.array([r]), np.array([r]), np.array([th]))[0] == pytest.approx(r * th)
    assert r * th - length <= th * tol * 2  # the polygon is shorter by O(tol)
    assert s["e"].sum() == pytest.approx(1.0)


def test_sample_arcs_are_consistent(gfiles):
    g = gfiles["prusaslicer_2.7.4_marlin2_arcs.gcode"]
    a = g.moves[g.moves["kind"] >= 2]
    assert len(a) > 5000
    assert np.allclose(a["r0"], a["r1"], atol=0.01)  # slicer's rounding only
    seg = g.segments(settings=Settings(chord_tolerance=0.002))
    ss = seg[np.isin(seg["move"], np.flatnonzero(g.moves["kind"] >= 2))]
    chords = np.hypot(ss["x1"] - ss["x0"], ss["y1"] - ss["y0"])
    by_move = np.bincount(ss["move"], weights=chords, minlength=len(g.moves))
    idx = np.flatnonzero(g.moves["kind"] >= 2)
    exact = arc_length(a["r0"], a["r1"], a["sweep"])
    assert np.all(by_move[idx] <= exact + 1e-9)
    assert np.all(exact - by_move[idx] <= np.abs(a["sweep"]) * 0.002 * 2 + 1e-9)


# ---------- errors ----------


def test_errors_name_file_and_line(tmp_path):
    p = tmp_path / "bad.gcode"
    p.write_bytes(b"G90\nG1 X1 Y1\nG1 X1..5 Y2\n")
    with pytest.raises(FileFormatError, match=r"bad\.gcode, line 3: .*not a number.*X1\.\.5"):
        read_gcode(p)


def test_binary_junk_is_refused(tmp_path):
    rng = np.random.default_rng(1)
    p = tmp_path / "junk.gcode"
    p.write_bytes(b"G1 X1\n" + rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(FileFormatError, match=r"junk\.gcode, line \d+: binary data"):
        read_gcode(p)
    with pytest.raises(FileFormatError, match="binary G-code"):
        parse_gcode(b"GCDE\x01\x00\x00\x00")
    with pytest.raises(FileFormatError, match="UTF-16"):
        parse_gcode("G1 X1\n".encode("utf-16"))
    # a text file with many lines that are not G-code
    with pytest.raises(FileFormatError, match="does not look like a G-code file"):
        parse_gcode(b"G1 X1\n" + b"%%% hello\n" * 50)


def test_non_utf8_comment_is_kept():
    data = b"G1 X1 Y1 ; caf\xe9 \xff\n;TYPE:Outer wall \xe9\nM83\nG1 X2 E1\n"
    g = parse_gcode(data)
    assert g.to_bytes() == data
    assert g.features == ("Outer wall \ufffd",)
    assert g.moves["is_extrusion"].tolist() == [False, True]


def test_truncated_files():
    with pytest.raises(FileFormatError, match=r"line 2: the file ends in the middle of a line"):
        parse_gcode(b"G1 X1 Y1\nG1 X2 Y-", path="cut.gcode")
    g = parse_gcode(b"G1 X1 Y1\nG1 X2 Y3")
    assert any("truncated" in w for w in g.warnings)
    head = b"G1 X1\n; prusaslicer_config = begin\n; layer_height = 0.2\n"
    with pytest.raises(FileFormatError, match="truncated"):
        parse_gcode(head)
    parse_gcode(head + b"; prusaslicer_config = end\n")


@pytest.mark.parametrize("data", [b"", b"\n\n", b"; just a comment\n"])
def test_no_commands(data):
    with pytest.raises(FileFormatError, match="no G-code commands"):
        parse_gcode(data)


def test_arc_errors():
    with pytest.raises(FileFormatError, match=r"line 2: arc .* without a centre"):
        parse_gcode(b"G1 X0 Y0\nG2 X1 Y1\n")
    with pytest.raises(FileFormatError, match="line 3: arcs outside the XY plane"):
        parse_gcode(b"G1 X0 Y0\nG18\nG2 X1 I1\n")
    with pytest.raises(FileFormatError, match="unknown position"):
        parse_gcode(b"G2 X1 Y1 I1 J0\n")


def test_missing_file(tmp_path):
    with pytest.raises(PrintabilityOSError, match="cannot read"):
        read_gcode(tmp_path / "nope.gcode")


# ---------- cross-check with pygcode, an independent parser ----------


@pytest.mark.parametrize("name", [n for n, *_ in LAYERS])
def test_words_agree_with_pygcode(gfiles, name):
    pygcode = pytest.importorskip("pygcode")
    g = gfiles[name]
    idx = g.moves["line"][::37]  # a sample of motion lines
    for i in idx.tolist():
        raw = g.line(i).decode()
        theirs = {w.letter: w.value for w in pygcode.Line(raw).block.words}
        ours = {chr(w["letter"]): w["value"] for w in g.line_words(i) if np.isfinite(w["value"])}
        ours[chr(g.lines["letter"][i])] = float(g.lines["major"][i])
        assert ours == theirs, raw


def test_simplify3d_dialect():
    text = """; G-Code generated by Simplify3D(R) Version 4.1.2
M82
G92 E0
; layer 1, Z = 0.25
; feature outer perimeter
; tool H0.250 W0.480
G1 Z0.25
G1 X0 Y0
G1 X10 Y0 E1
; feature support
; tool H0.250 W0.400
G1 X10 Y10 E2
; layer 2, Z = 0.5
G1 Z0.5
; feature infill
G1 X0 Y10 E3
"""
    g = parse_gcode(text.encode())
    assert (g.dialect, g.slicer) == ("simplify3d", "Simplify3D")
    assert g.layers["z"].tolist() == [0.25, 0.5]
    assert g.layers["height"].tolist() == [0.25, 0.25]
    ext = g.moves[g.moves["is_extrusion"]]
    assert ext["width"].tolist() == [0.48, 0.4, 0.4]
    assert [g.feature_categories[f] for f in ext["feature"]] == ["outer_wall", "support",
                                                                  "sparse_infill"]


def test_bambu_markers_with_crlf():
    text = ("M83\r\n; CHANGE_LAYER\r\n; Z_HEIGHT: 0.2\r\n; LAYER_HEIGHT: 0.2\r\n"
            "; FEATURE: Outer wall\r\n; LINE_WIDTH: 0.42\r\nG1 X0 Y0 Z0.2\r\nG1 X5 E1\r\n"
            "; CHANGE_LAYER\r\n; Z_HEIGHT: 0.4\r\n; LAYER_HEIGHT: 0.2\r\nG1 Z0.4\r\nG1 X0 E1\r\n")
    g = parse_gcode(text.encode())
    assert g.dialect == "bambu" and g.layers["z"].tolist() == [0.2, 0.4]
    assert g.features == ("Outer wall",) and g.moves["width"][1] == 0.42
    # a marker inside another line's comment is not a layer change
    g2 = parse_gcode(text.replace("G1 X5 E1", "G1 X5 E1 ; CHANGE_LAYER").encode())
    assert len(g2.layers) == 2


@pytest.mark.parametrize("name", ["orcaslicer_2.3.0b2_klipper_arcs.gcode",
                                  "slic3rpe_1.33_arcwelder_benchy.gcode"])
def test_interpreted_engine_gives_the_same_file(gfiles, name):
    g = gfiles[name]
    head = b"".join(g.data.splitlines(keepends=True)[:3000])
    a = parse_gcode(head, engine="numba")
    b = parse_gcode(head, engine="python")
    for table in ("lines", "words", "moves", "layers"):
        x, y = getattr(a, table), getattr(b, table)
        for f in x.dtype.names:
            assert np.array_equal(x[f], y[f], equal_nan=x[f].dtype.kind == "f"), (table, f)


def test_line_layer_column(gfiles):
    g = gfiles["prusaslicer_2.7.4_marlin2_arcs.gcode"]
    L = g.layers
    assert (g.lines["layer"][: L["line"][0]] == -1).all()
    for k in (0, 50, len(L) - 1):
        assert g.lines["layer"][L["line"][k]] == k
        assert g.line(int(L["line"][k])).startswith(b";LAYER_CHANGE")
    assert (g.moves["layer"][L["first_move"][5] : L["end_move"][5]] == 5).all()


def test_memory_limit_is_checked_before_parsing():
    from printability.errors import ResourceError

    with pytest.raises(ResourceError, match="max_memory"):
        parse_gcode(b"G1 X1\n" * 1000, settings=Settings(max_memory=10_000))


_coord = st.integers(-500, 500).map(lambda k: k / 10)
_op = st.one_of(
    st.sampled_from(["G90", "G91", "M82", "M83", "G92 E0", "G20", "G21"]),
    st.tuples(st.sampled_from(["G0", "G1"]), _coord, _coord, _coord),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(_op, max_size=25))
def test_modal_state_against_a_plain_model(ops):
    """Marlin semantics, written out the obvious way, on random programs."""
    lines = ["G90", "G21", "M82", "G92 E0", "G1 X0 Y0"]
    x = y = e = 0.0
    abs_xyz = abs_e = True
    unit = 1.0
    want = [(0.0, 0.0, 0.0)]
    for op in ops:
        if isinstance(op, str):
            lines.append(op)
            if op == "G90":
                abs_xyz = abs_e = True
            elif op == "G91":
                abs_xyz = abs_e = False
            elif op == "M82":
                abs_e = True
            elif op == "M83":
                abs_e = False
            elif op == "G92 E0":
                e = 0.0
            elif op == "G20":
                unit = 25.4
            elif op == "G21":
                unit = 1.0
            continue
        code, vx, vy, ve = op
        lines.append(f"{code} X{vx} Y{vy} E{ve}")
        nx = x + vx * unit if not abs_xyz else vx * unit
        ny = y + vy * unit if not abs_xyz else vy * unit
        de = ve * unit if not abs_e else ve * unit - e
        e = e + de if not abs_e else ve * unit
        want.append((nx, ny, de))
        x, y = nx, ny
    m = parse_gcode(("\n".join(lines) + "\n").encode(), flavor="marlin").moves
    got = np.column_stack([m["x1"], m["y1"], m["e"]])
    assert np.allclose(got, np.array(want).reshape(-1, 3), rtol=0, atol=1e-9)


def test_logical_e_position():
    m = moves_of("M82\nG92 E0\nG1 X0 Y0\nG1 X1 E2\nG92 E10\nG1 X2 E11\nM83\nG1 X3 E0.5\n")
    assert m["e_pos"].tolist() == [0, 2, 11, 11.5]
    assert m["e"].tolist() == [0, 2, 1, 0.5]


_FUZZ_LINES = st.one_of(
    st.sampled_from([
        "G1 X1 Y1", "G1 X5 E1", "G2 X0 Y0 I1 J0", "G3 X1 Y1 R2", "G3 I-1 J0 P2", "G92 E0",
        "G91", "G90", "M83", "M82", "G20", "G21", "G10", "G11", "T1", "G28", "G28 X",
        ";LAYER_CHANGE", ";Z:0.4", ";TYPE:Support material", ";WIDTH:0.4", ";LAYER:3",
        "; CHANGE_LAYER", ";WIPE_START", ";WIPE_END", "G1 Z0.2", "G1 X Y", "M84 X Y E",
        "G18", "G17", "EXCLUDE_OBJECT_START NAME=a", "N3 G1 X2*12", "", "G92 X0",
    ]),
    st.lists(st.sampled_from(list("GMXYZEIJRP0123456789.- ;")), max_size=12).map("".join),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(_FUZZ_LINES, min_size=1, max_size=30))
def test_random_programs_parse_or_fail_cleanly(lines):
    data = ("\n".join(lines) + "\n").encode()
    try:
        g = parse_gcode(data, path="fuzz.gcode")
    except FileFormatError as exc:
        assert str(exc).startswith("fuzz.gcode")
        return
    assert g.to_bytes() == data
    assert len(g.moves) == sum(
        1 for k in range(len(g)) if g.lines["kind"][k] == 2 and g.lines["letter"][k] == 71
        and 0 <= g.lines["major"][k] <= 3 and g.lines["minor"][k] < 0
    )
    ext = g.moves["is_extrusion"]
    assert np.isfinite(g.moves["x1"][ext]).all()
    linearise(g.moves[ext], 0.01)


@pytest.mark.parametrize("name", ["prusaslicer_2.7.4_marlin2_arcs.gcode",
                                  "bambustudio_1.10_klipper_arcs.gcode",
                                  "orcaslicer_2.3.0b2_klipper_arcs.gcode"])
def test_arc_lengths_agree_with_the_slicers_flow(gfiles, name):
    """The slicer fed E in proportion to each move's true length. With our arc
    sweeps and lengths, the E per mm of arcs must match that of straight moves
    of the same width: a wrong sweep (the complementary arc, a missed full
    turn) would be off by a large factor."""
    from printability.sources.gcode import bead_widths

    g = gfiles[name]
    m = g.moves
    ext = m["is_extrusion"] & (m["layer"] >= 0) & np.isfinite(m["width"])
    arc = m["kind"] >= 2
    length = np.where(arc, arc_length(m["r0"], m["r1"], m["sweep"]),
                      np.hypot(m["x1"] - m["x0"], m["y1"] - m["y0"]))
    h = g.layers["height"][np.maximum(m["layer"], 0)]
    w = bead_widths(m["e"], length, h, filament_diameter=1.75, model="stadium")
    ratio = w / m["width"]
    # walls: one flow per profile (Orca combines sparse infill of two layers, bridges
    # use their own flow, so those do not follow the layer height)
    walls = np.isin(g.feature_category_of_moves(), ["outer_wall", "inner_wall"])
    sel = ext & walls & (length > 2.0)
    line_ratio = np.median(ratio[sel & ~arc])
    arcs = ratio[sel & arc]
    assert len(arcs) > 200
    # flow ratios differ between profiles (Orca/Bambu ~0.96-0.98), not between move kinds
    assert np.median(arcs) == pytest.approx(line_ratio, rel=2e-3)
    assert np.mean(np.abs(arcs / line_ratio - 1) < 0.02) > 0.95


@pytest.mark.parametrize("eol", [b"\n", b"\r\n", b"\r"])
def test_layer_markers_with_any_line_ending(eol):
    data = eol.join([b"G90", b"M83", b";LAYER_CHANGE", b";Z:0.2", b";HEIGHT:0.2",
                     b";TYPE:Outer wall", b";WIDTH:0.45", b"G1 X0 Y0 Z0.2", b"G1 X10 E1",
                     b";LAYER_CHANGE", b";Z:0.4", b"G1 Z0.4", b"G1 X0 E1"]) + eol
    g = parse_gcode(data)
    assert g.dialect == "prusa" and g.layers["z"].tolist() == [0.2, 0.4]
    assert g.layers["height"].tolist() == pytest.approx([0.2, 0.2])
    assert g.moves["width"].tolist() == [0.45] * 4 and g.features == ("Outer wall",)
    assert g.to_bytes() == data
