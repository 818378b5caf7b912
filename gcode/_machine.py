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
from typing import NamedTuple

import numpy as np

from gcode._lexer import KIND_COMMAND
from gcode.flavors import flavor_named
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["ERR_MESSAGES", "MOVE_FIELDS", "run_machine"]

# error codes
ERR_BAD_WORD = 1
ERR_NO_CENTRE = 2
ERR_R_SAME_POINT = 3
ERR_PLANE = 4
ERR_ZERO_RADIUS = 5
ERR_UNKNOWN_START = 6
ERR_BAD_G92 = 7

ERR_MESSAGES = {
    ERR_BAD_WORD: "a word of this move is not a number (expected letter + number, e.g. X12.5)",
    ERR_NO_CENTRE: "arc (G2/G3) without a centre: expected I/J offsets or an R radius",
    ERR_R_SAME_POINT: "arc (G2/G3) given by R must end somewhere else than it starts",
    ERR_PLANE: "arcs outside the XY plane (G18/G19) are not supported",
    ERR_ZERO_RADIUS: "arc (G2/G3) with zero radius (I and J both 0)",
    ERR_UNKNOWN_START: "arc (G2/G3) from an unknown position (no absolute X/Y move or G28 "
                       "before it)",
    ERR_BAD_G92: "a word of this G92 is not a number",
}

# move flags
MF_E_RELATIVE = 1
MF_XYZ_RELATIVE = 2
MF_INCH = 4
MF_RETRACTED = 8  # firmware retraction (G10) in force

# flavor codes (gcode.flavors.Flavor.reader_code): how G90/G91 touch the extruder
FLAVOR_G90_SETS_E = 0  # Marlin, generic: G90/G91 set E absolute/relative too
FLAVOR_E_SEPARATE = 1  # Klipper, RepRapFirmware: M82/M83 alone; G91 makes E relative

_G, _M, _T = 71, 77, 84  # command letters
_TWO_PI = 2.0 * math.pi

# The modal position (a float64 array, so that helpers can update it): machine X Y Z
# (NaN: unknown), the G92 offsets, the extruder's logical position, the feed
_X, _Y, _Z, _OX, _OY, _OZ, _EPOS, _FEED = range(8)
# words present on a move (a bit mask)
_HX, _HY, _HZ, _HE, _HI, _HJ, _HR = 1, 2, 4, 8, 16, 32, 64

try:
    from numba.extending import register_jitable
except ImportError:  # pragma: no cover - numba is a declared dependency

    def register_jitable(fn=None, **_options):
        return fn if fn is not None else (lambda f: f)

# The helpers run interpreted as they are (engine "python") and are compiled into the kernel
# when :func:`_machine_impl` is. They allocate nothing: no reference counting, which would
# also keep LLVM from inlining them.
_jitable = register_jitable(_nrt=False)


class _Tokens(NamedTuple):
    """The lexer's tables the machine reads (:func:`gcode._lexer.lex`)."""

    kind: np.ndarray
    letter: np.ndarray
    major: np.ndarray
    minor: np.ndarray
    word_first: np.ndarray
    word_count: np.ndarray
    bad_column: np.ndarray
    w_letter: np.ndarray
    w_value: np.ndarray
    w_flags: np.ndarray


class _Moves(NamedTuple):
    """One row per G0-G3 line (see the module's conventions)."""

    line: np.ndarray
    kind: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    z0: np.ndarray
    x1: np.ndarray
    y1: np.ndarray
    z1: np.ndarray
    e: np.ndarray
    feed: np.ndarray
    tool: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    sweep: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    flags: np.ndarray
    e_pos: np.ndarray


MOVE_FIELDS = _Moves._fields


@register_jitable
def _new_moves(n):
    return _Moves(
        np.empty(n, np.int64), np.empty(n, np.uint8), np.empty(n), np.empty(n), np.empty(n),
        np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.int16),
        np.full(n, np.nan), np.full(n, np.nan), np.zeros(n), np.full(n, np.nan),
        np.full(n, np.nan), np.zeros(n, np.uint8), np.empty(n),
    )


@register_jitable
def _first_moves(mv, n):
    return _Moves(
        mv.line[:n], mv.kind[:n], mv.x0[:n], mv.y0[:n], mv.z0[:n], mv.x1[:n], mv.y1[:n],
        mv.z1[:n], mv.e[:n], mv.feed[:n], mv.tool[:n], mv.cx[:n], mv.cy[:n], mv.sweep[:n],
        mv.r0[:n], mv.r1[:n], mv.flags[:n], mv.e_pos[:n],
    )


@_jitable
def _move_words(tok, li, unit, feed):
    """The words of a move: (mask of those present, X Y Z E I J R values, P turns, feed);
    valueless and quoted words are not coordinates."""
    has = 0
    vx = vy = vz = ve = vi = vj = vr = 0.0
    p_turns = 0
    for k in range(tok.word_first[li], tok.word_first[li] + tok.word_count[li]):
        if tok.w_flags[k] != 0:
            continue
        c = tok.w_letter[k]
        v = tok.w_value[k]
        if c == 88:
            has |= _HX
            vx = v
        elif c == 89:
            has |= _HY
            vy = v
        elif c == 90:
            has |= _HZ
            vz = v
        elif c == 69:
            has |= _HE
            ve = v
        elif c == 70:
            feed = v * unit
        elif c == 73:
            has |= _HI
            vi = v
        elif c == 74:
            has |= _HJ
            vj = v
        elif c == 82:
            has |= _HR
            vr = v
        elif c == 80:
            p_turns = int(v)
    return has, vx, vy, vz, ve, vi, vj, vr, p_turns, feed


@_jitable
def _arc(x, y, nx, ny, mj, has, vi, vj, vr, unit, p_turns):
    """(error, centre x, centre y, signed sweep, start radius, end radius) of a G2 (``mj``
    2) or G3 from (x, y) to (nx, ny) given by I/J or R."""
    if not (x == x and y == y):  # NaN start
        return ERR_UNKNOWN_START, 0.0, 0.0, 0.0, 0.0, 0.0
    if has & (_HI | _HJ):
        cx = x + vi * unit
        cy = y + vj * unit
        if vi == 0.0 and vj == 0.0:
            return ERR_ZERO_RADIUS, 0.0, 0.0, 0.0, 0.0, 0.0
    elif has & _HR:
        dx = nx - x
        dy = ny - y
        d = math.sqrt(dx * dx + dy * dy)
        if d < 1e-9:
            return ERR_R_SAME_POINT, 0.0, 0.0, 0.0, 0.0, 0.0
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
        return ERR_NO_CENTRE, 0.0, 0.0, 0.0, 0.0, 0.0
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
    return 0, cx, cy, ang, math.sqrt(sx * sx + sy * sy), math.sqrt(tx * tx + ty * ty)


@_jitable
def _move(tok, li, mv, nm, pos, unit, xyz_rel, e_rel, tool, flags, plane):
    """Write the G0-G3 of line ``li`` as move ``nm`` and advance ``pos``; an error code or 0."""
    mj = tok.major[li]
    has, vx, vy, vz, ve, vi, vj, vr, p_turns, feed = _move_words(tok, li, unit, pos[_FEED])
    pos[_FEED] = feed
    x = pos[_X]
    y = pos[_Y]
    z = pos[_Z]
    nx = x
    ny = y
    nz = z
    if has & _HX:
        nx = x + vx * unit if xyz_rel else vx * unit + pos[_OX]
    if has & _HY:
        ny = y + vy * unit if xyz_rel else vy * unit + pos[_OY]
    if has & _HZ:
        nz = z + vz * unit if xyz_rel else vz * unit + pos[_OZ]
    de = 0.0
    if has & _HE:
        if e_rel:
            de = ve * unit
            pos[_EPOS] += de
        else:
            de = ve * unit - pos[_EPOS]
            pos[_EPOS] = ve * unit
    mv.line[nm] = li
    mv.kind[nm] = mj
    mv.x0[nm] = x
    mv.y0[nm] = y
    mv.z0[nm] = z
    mv.x1[nm] = nx
    mv.y1[nm] = ny
    mv.z1[nm] = nz
    mv.e[nm] = de
    mv.feed[nm] = feed
    mv.tool[nm] = tool
    mv.flags[nm] = flags
    mv.e_pos[nm] = pos[_EPOS]
    if mj >= 2:
        if plane != 17:
            return ERR_PLANE
        err, cx, cy, sweep, r0, r1 = _arc(x, y, nx, ny, mj, has, vi, vj, vr, unit, p_turns)
        if err:
            return err
        mv.cx[nm] = cx
        mv.cy[nm] = cy
        mv.sweep[nm] = sweep
        mv.r0[nm] = r0
        mv.r1[nm] = r1
    pos[_X] = nx
    pos[_Y] = ny
    pos[_Z] = nz
    return 0


@_jitable
def _set_axis(pos, axis, offset, v):
    """G92 of one axis: a known axis gets an offset; an unknown one is placed there."""
    if pos[axis] == pos[axis]:
        pos[offset] = pos[axis] - v
    else:
        pos[axis] = v
        pos[offset] = 0.0


@_jitable
def _g92(tok, li, unit, pos):
    """G92 (set position), G92.1 (drop the offsets); other G92.x change nothing."""
    mn = tok.minor[li]
    if mn == 1:
        pos[_OX] = 0.0
        pos[_OY] = 0.0
        pos[_OZ] = 0.0
        return
    if mn >= 0:
        return
    for k in range(tok.word_first[li], tok.word_first[li] + tok.word_count[li]):
        if tok.w_flags[k] != 0:
            continue
        c = tok.w_letter[k]
        v = tok.w_value[k] * unit
        if c == 88:
            _set_axis(pos, _X, _OX, v)
        elif c == 89:
            _set_axis(pos, _Y, _OY, v)
        elif c == 90:
            _set_axis(pos, _Z, _OZ, v)
        elif c == 69:
            pos[_EPOS] = v


@_jitable
def _g28(tok, li, pos):
    """G28: the axes named (all when none is) go home, to 0, and lose their offsets."""
    any_axis = False
    for k in range(tok.word_first[li], tok.word_first[li] + tok.word_count[li]):
        c = tok.w_letter[k]
        if c == 88 or c == 89 or c == 90:
            axis = c - 88
            pos[_X + axis] = 0.0
            pos[_OX + axis] = 0.0
            any_axis = True
    if not any_axis:
        for axis in range(3):
            pos[_X + axis] = 0.0
            pos[_OX + axis] = 0.0


@_jitable
def _is_retraction(tok, li):
    """Whether a G10 is firmware retraction: not if it carries tool/offset words (RRF
    G10 P.., CNC G10 L..)."""
    for k in range(tok.word_first[li], tok.word_first[li] + tok.word_count[li]):
        if tok.w_letter[k] == 80 or tok.w_letter[k] == 76:
            return False
    return True


def _machine_impl(tok, flavor, n_moves):
    mv = _new_moves(n_moves)
    pos = np.zeros(8)
    pos[_X] = pos[_Y] = pos[_Z] = pos[_FEED] = np.nan
    abs_xyz = True
    abs_e = True  # M82 state
    unit = 1.0
    tool = 0
    plane = 17
    retracted = False
    nm = 0
    err = 0
    err_line = -1
    for li in range(tok.kind.shape[0]):
        if tok.kind[li] != KIND_COMMAND:
            continue
        letter = tok.letter[li]
        mj = tok.major[li]
        mn = tok.minor[li]
        if letter == _T:
            tool = mj
        elif letter == _M:
            if mj == 82:
                abs_e = True
            elif mj == 83:
                abs_e = False
        elif letter != _G:
            continue
        elif mj <= 3 and mn < 0:
            err = ERR_BAD_WORD if tok.bad_column[li] >= 0 else 0
            if err == 0:
                xyz_rel = not abs_xyz
                e_rel = not abs_e if flavor == FLAVOR_G90_SETS_E else (not abs_e) or xyz_rel
                flags = (MF_E_RELATIVE if e_rel else 0) | (MF_XYZ_RELATIVE if xyz_rel else 0) \
                    | (MF_INCH if unit != 1.0 else 0) | (MF_RETRACTED if retracted else 0)
                err = _move(tok, li, mv, nm, pos, unit, xyz_rel, e_rel, tool, flags, plane)
            if err:
                err_line = li
                break
            nm += 1
        elif mj == 92:
            if tok.bad_column[li] >= 0:
                err = ERR_BAD_G92
                err_line = li
                break
            _g92(tok, li, unit, pos)
        elif (mj == 90 or mj == 91) and mn < 0:
            abs_xyz = mj == 90
            if flavor == FLAVOR_G90_SETS_E:
                abs_e = abs_xyz
        elif mj == 20 or mj == 21:
            unit = 25.4 if mj == 20 else 1.0
        elif mj == 17 or mj == 18 or mj == 19:
            plane = mj
        elif mj == 28:
            _g28(tok, li, pos)
        elif mj == 10 and mn < 0:
            if _is_retraction(tok, li):
                retracted = True
        elif mj == 11 and mn < 0:
            retracted = False
    return err, err_line, _first_moves(mv, nm)


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
    tok = _Tokens(
        lines["kind"], lines["letter"], lines["major"], lines["minor"],
        lines["word_first"], lines["word_count"], lines["bad_column"],
        words["letter"], words["value"], words["flags"],
    )
    err, err_line, mv = _kernel(engine)(tok, flavor_named(flavor).reader_code, int(is_move.sum()))
    return int(err), int(err_line), dict(zip(MOVE_FIELDS, mv, strict=True))
