"""The modal state machine: from token tables to a table of moves.

One sequential pass over the lines keeps the modal state a firmware keeps
(absolute/relative axes, absolute/relative E, units, G92 offsets, feed,
tool, plane, firmware retraction) and writes one row per G0/G1/G2/G3 line.
Compiled with numba (the same code runs interpreted for cross-checks).

Conventions
-----------
* Positions are *machine* coordinates in mm: a ``G92 X10`` shifts the
  logical frame, so a later ``G1 X20`` is stored where the nozzle really
  goes. Axes never set yet are NaN (the start of a file is unknown until the
  first absolute move or a G28, which is taken to home to 0).
* ``e`` is the filament fed by the move, mm (negative: retraction);
  ``e_pos`` the extruder's logical position after it (what an absolute-E
  file would write; G92 E resets it), mm.
* Arcs (G17 plane) keep their centre, signed sweep (radians, CCW positive)
  and start/end radii; :mod:`gcode.arcs` linearises them.

Flavours differ only in how G90/G91 touch the extruder: Marlin's and
"generic" G90/G91 set the E mode too (a G90 after M83 makes E absolute),
Klipper and RepRapFirmware keep M82/M83 separate and treat E as relative
whenever G91 is in force.
"""

from __future__ import annotations

import math

import numpy as np

from gcode.flavors import flavor_named
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["ERR_MESSAGES", "MOVE_FIELDS", "run_machine"]

ERR_MESSAGES = {
    1: "a word of this move is not a number (expected letter + number, e.g. X12.5)",
    2: "arc (G2/G3) without a centre: expected I/J offsets or an R radius",
    3: "arc (G2/G3) given by R must end somewhere else than it starts",
    4: "arcs outside the XY plane (G18/G19) are not supported",
    5: "arc (G2/G3) with zero radius (I and J both 0)",
    6: "arc (G2/G3) from an unknown position (no absolute X/Y move or G28 before it)",
    7: "a word of this G92 is not a number",
}

MOVE_FIELDS = (
    "line", "kind", "x0", "y0", "z0", "x1", "y1", "z1", "e", "feed", "tool",
    "cx", "cy", "sweep", "r0", "r1", "flags", "e_pos",
)

# move flags
MF_E_RELATIVE = 1
MF_XYZ_RELATIVE = 2
MF_INCH = 4
MF_RETRACTED = 8  # firmware retraction (G10) in force

_TWO_PI = 2.0 * math.pi


def _machine_impl(kind, letter, major, minor, wfirst, wcount, bad,
                  w_letter, w_value, w_flags, flavor, n_moves):
    nl = kind.shape[0]
    m_line = np.empty(n_moves, np.int64)
    m_kind = np.empty(n_moves, np.uint8)
    m_x0 = np.empty(n_moves)
    m_y0 = np.empty(n_moves)
    m_z0 = np.empty(n_moves)
    m_x1 = np.empty(n_moves)
    m_y1 = np.empty(n_moves)
    m_z1 = np.empty(n_moves)
    m_e = np.empty(n_moves)
    m_feed = np.empty(n_moves)
    m_tool = np.empty(n_moves, np.int16)
    m_cx = np.full(n_moves, np.nan)
    m_cy = np.full(n_moves, np.nan)
    m_sweep = np.zeros(n_moves)
    m_r0 = np.full(n_moves, np.nan)
    m_r1 = np.full(n_moves, np.nan)
    m_flags = np.zeros(n_moves, np.uint8)
    m_epos = np.empty(n_moves)

    x = np.nan
    y = np.nan
    z = np.nan
    ox = 0.0
    oy = 0.0
    oz = 0.0
    epos = 0.0
    feed = np.nan
    abs_xyz = True
    abs_e = True  # M82 state
    unit = 1.0
    tool = 0
    plane = 17
    retracted = False
    nm = 0
    err = 0
    err_line = -1

    for li in range(nl):
        if kind[li] != 2:  # KIND_COMMAND
            continue
        L = letter[li]
        mj = major[li]
        mn = minor[li]
        if L == 84:  # T
            tool = mj
            continue
        if L == 77:  # M
            if mj == 82:
                abs_e = True
            elif mj == 83:
                abs_e = False
            continue
        if L != 71:
            continue
        # G codes
        if mj <= 3 and mn < 0:
            if bad[li] >= 0:
                err = 1
                err_line = li
                break
            hx = False
            hy = False
            hz = False
            he = False
            hi = False
            hj = False
            hr = False
            vx = 0.0
            vy = 0.0
            vz = 0.0
            ve = 0.0
            vi = 0.0
            vj = 0.0
            vr = 0.0
            p_turns = 0
            for k in range(wfirst[li], wfirst[li] + wcount[li]):
                if w_flags[k] != 0:
                    continue  # valueless or quoted: not a coordinate
                c = w_letter[k]
                v = w_value[k]
                if c == 88:
                    hx = True
                    vx = v
                elif c == 89:
                    hy = True
                    vy = v
                elif c == 90:
                    hz = True
                    vz = v
                elif c == 69:
                    he = True
                    ve = v
                elif c == 70:
                    feed = v * unit
                elif c == 73:
                    hi = True
                    vi = v
                elif c == 74:
                    hj = True
                    vj = v
                elif c == 82:
                    hr = True
                    vr = v
                elif c == 80:
                    p_turns = int(v)
            xyz_rel = not abs_xyz
            if flavor == 0:
                e_rel = not abs_e
            else:
                e_rel = (not abs_e) or (not abs_xyz)
            nx = x
            ny = y
            nz = z
            if hx:
                nx = x + vx * unit if xyz_rel else vx * unit + ox
            if hy:
                ny = y + vy * unit if xyz_rel else vy * unit + oy
            if hz:
                nz = z + vz * unit if xyz_rel else vz * unit + oz
            de = 0.0
            if he:
                if e_rel:
                    de = ve * unit
                    epos += de
                else:
                    de = ve * unit - epos
                    epos = ve * unit
            m_line[nm] = li
            m_kind[nm] = mj
            m_x0[nm] = x
            m_y0[nm] = y
            m_z0[nm] = z
            m_x1[nm] = nx
            m_y1[nm] = ny
            m_z1[nm] = nz
            m_e[nm] = de
            m_feed[nm] = feed
            m_tool[nm] = tool
            fl = 0
            if e_rel:
                fl |= 1
            if xyz_rel:
                fl |= 2
            if unit != 1.0:
                fl |= 4
            if retracted:
                fl |= 8
            m_flags[nm] = fl
            m_epos[nm] = epos
            if mj >= 2:
                if plane != 17:
                    err = 4
                    err_line = li
                    break
                if not (x == x and y == y):  # NaN start
                    err = 6
                    err_line = li
                    break
                if hi or hj:
                    cx = x + vi * unit
                    cy = y + vj * unit
                    if vi == 0.0 and vj == 0.0:
                        err = 5
                        err_line = li
                        break
                elif hr:
                    dx = nx - x
                    dy = ny - y
                    d = math.sqrt(dx * dx + dy * dy)
                    if d < 1e-9:
                        err = 3
                        err_line = li
                        break
                    r = vr * unit
                    h2 = (r - 0.5 * d) * (r + 0.5 * d)
                    h = math.sqrt(h2) if h2 > 0.0 else 0.0
                    # Marlin: e = +1 for CW with R>0 or CCW with R<0
                    sgn = 1.0
                    if (mj == 2) != (r < 0.0):
                        sgn = -1.0
                    cx = 0.5 * (x + nx) - sgn * h * dy / d
                    cy = 0.5 * (y + ny) + sgn * h * dx / d
                else:
                    err = 2
                    err_line = li
                    break
                sx = x - cx
                sy = y - cy
                tx = nx - cx
                ty = ny - cy
                ang = math.atan2(sx * ty - sy * tx, sx * tx + sy * ty)
                if ang < 0.0:
                    ang += _TWO_PI
                if mj == 2:
                    ang -= _TWO_PI
                if abs(ang) < 1e-9 and abs(nx - x) < 1e-9 and abs(ny - y) < 1e-9:
                    ang = _TWO_PI
                if p_turns > 0:
                    ang += p_turns * (_TWO_PI if mj == 3 else -_TWO_PI)
                m_cx[nm] = cx
                m_cy[nm] = cy
                m_sweep[nm] = ang
                m_r0[nm] = math.sqrt(sx * sx + sy * sy)
                m_r1[nm] = math.sqrt(tx * tx + ty * ty)
            nm += 1
            x = nx
            y = ny
            z = nz
        elif mj == 92:
            if bad[li] >= 0:
                err = 7
                err_line = li
                break
            if mn == 1:  # G92.1: drop the offsets
                ox = 0.0
                oy = 0.0
                oz = 0.0
                continue
            if mn >= 0:
                continue
            for k in range(wfirst[li], wfirst[li] + wcount[li]):
                if w_flags[k] != 0:
                    continue
                c = w_letter[k]
                v = w_value[k] * unit
                if c == 88:
                    if x == x:
                        ox = x - v
                    else:
                        x = v
                        ox = 0.0
                elif c == 89:
                    if y == y:
                        oy = y - v
                    else:
                        y = v
                        oy = 0.0
                elif c == 90:
                    if z == z:
                        oz = z - v
                    else:
                        z = v
                        oz = 0.0
                elif c == 69:
                    epos = v
        elif mj == 90 and mn < 0:
            abs_xyz = True
            if flavor == 0:
                abs_e = True
        elif mj == 91 and mn < 0:
            abs_xyz = False
            if flavor == 0:
                abs_e = False
        elif mj == 20:
            unit = 25.4
        elif mj == 21:
            unit = 1.0
        elif mj == 17 or mj == 18 or mj == 19:
            plane = mj
        elif mj == 28:
            any_axis = False
            for k in range(wfirst[li], wfirst[li] + wcount[li]):
                c = w_letter[k]
                if c == 88:
                    x = 0.0
                    ox = 0.0
                    any_axis = True
                elif c == 89:
                    y = 0.0
                    oy = 0.0
                    any_axis = True
                elif c == 90:
                    z = 0.0
                    oz = 0.0
                    any_axis = True
            if not any_axis:
                x = 0.0
                y = 0.0
                z = 0.0
                ox = 0.0
                oy = 0.0
                oz = 0.0
        elif mj == 10 and mn < 0:
            # firmware retraction, unless it carries tool/offset words (RRF G10 P.., CNC G10 L..)
            plain = True
            for k in range(wfirst[li], wfirst[li] + wcount[li]):
                if w_letter[k] == 80 or w_letter[k] == 76:
                    plain = False
            if plain:
                retracted = True
        elif mj == 11 and mn < 0:
            retracted = False

    return (err, err_line, m_line[:nm], m_kind[:nm], m_x0[:nm], m_y0[:nm], m_z0[:nm],
            m_x1[:nm], m_y1[:nm], m_z1[:nm], m_e[:nm], m_feed[:nm], m_tool[:nm],
            m_cx[:nm], m_cy[:nm], m_sweep[:nm], m_r0[:nm], m_r1[:nm], m_flags[:nm],
            m_epos[:nm])


_compiled = None


def _kernel(engine: str):
    global _compiled
    if engine == "python":
        return _machine_impl
    if _compiled is None:
        try:
            import numba
        except ImportError:  # pragma: no cover
            _compiled = _machine_impl
        else:
            _compiled = numba.njit(cache=True, nogil=True)(_machine_impl)
    return _compiled


def run_machine(lines: dict, words: dict, *, flavor: str, engine: str = "numba"):
    """Run the state machine over token tables (see :func:`gcode._lexer.lex`).

    Returns
    -------
    err, err_line, moves
        ``err`` is 0 or a key of :data:`ERR_MESSAGES`, ``err_line`` the
        0-based line it concerns; ``moves`` a dict of arrays (:data:`MOVE_FIELDS`).
    """
    is_move = (lines["kind"] == 2) & (lines["letter"] == 71) & (lines["major"] <= 3) & (
        lines["major"] >= 0
    ) & (lines["minor"] < 0)
    out = _kernel(engine)(
        lines["kind"], lines["letter"], lines["major"], lines["minor"],
        lines["word_first"], lines["word_count"], lines["bad_column"],
        words["letter"], words["value"], words["flags"],
        flavor_named(flavor).reader_code, int(is_move.sum()),
    )
    moves = dict(zip(MOVE_FIELDS, out[2:], strict=True))
    return int(out[0]), int(out[1]), moves
