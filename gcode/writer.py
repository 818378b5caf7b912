"""G-code writer for machines with a rotary axis turning the nozzle (T-T-R).

Two ways to produce lines:

* :class:`Emitter` writes a program from scratch (the generator): it keeps the
  machine state (position, unwrapped rotary coordinate, E counter, feed) and
  formats each move with the options of :class:`WriterOptions`;
* :func:`edit_line` rewrites one existing line (the post-processor): it
  replaces or adds address words and keeps every other byte of the line
  (spacing, comment, line terminator) as it was (:mod:`gcode.edit`, re-exported here).

Rotary conventions (docs/design.md §3): the axis letter is configurable (ISO 841:
C turns about Z), coordinates are degrees, unwrapped (shortest signed step),
a nozzle with a symmetry period (an ellipse: 180°) is turned to the nearest
equivalent orientation, a round nozzle (period 0) gets no rotary word at all,
G2/G3 never carry a rotary word (:meth:`Emitter.arc` refuses to turn; callers
linearise arcs that must turn), orientation changes during an extrusion are
done by rotation-only moves without E (nothing is deposited while turning),
and orientation changes between extrusions are folded into the travel move.
With ``unwind=True`` (a cabled head) the coordinate is brought back towards
zero on every travel, and always kept within the axis limits.

Feed rate (F) per policy, see :func:`gcode.rotary.feed_for_move`; E from the
bead cross-section (:func:`gcode.rotary.e_per_mm`) and filament diameter,
relative (M83) or absolute (M82); every number is rounded to the precision of
its kind and the rounding error of E is carried, never accumulated.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from gcode.edit import edit_e, edit_line, simple_move_words
from gcode.rotary import BEAD_MODELS, e_per_mm, feed_for_move, nearest_equivalent
from printability.base.errors import InputError, UnknownOptionError

__all__ = [
    "MARKER",
    "Emitter",
    "WriterOptions",
    "edit_e",
    "edit_line",
    "format_number",
    "header_lines",
    "simple_move_words",
]

#: First words of the comment that marks a file written or post-processed by printability.
MARKER = "; printability"

_FEED_POLICIES = ("xy", "euclidean", "inverse-time")


_FIXED = tuple(f"%.{d}f" for d in range(18))


def format_number(value: float, decimals: int) -> str:
    """``value`` with at most ``decimals`` decimals, trailing zeros dropped, never ``-0``.

    Raises
    ------
    ValueError
        ``value`` is not finite: the last guard that no ``inf``/``nan`` reaches a file.
    """
    # printf-style with a prebuilt spec: the same correctly rounded digits as
    # f"{value:.{decimals}f}" at half the cost (it runs for every number written)
    text = _FIXED[decimals] % value if 0 <= decimals < 18 else f"{value:.{decimals}f}"
    if text[-1] in "fn":  # "inf", "nan": no firmware reads them as we would mean them
        raise ValueError(f"refusing to write a non-finite number ({value!r}) into G-code")
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    if text in ("-0", ""):
        text = "0"
    return text


@dataclass(frozen=True)
class WriterOptions:
    """How moves are written.

    Attributes
    ----------
    letter
        Rotary axis word (ISO 841: C turns about Z).
    period
        Symmetry period of the nozzle, degrees: 0 for a round nozzle (no
        rotary words are written), 180 for an ellipse, 360 for none.
    angle_min, angle_max
        Axis travel limits, degrees (±inf for a slip-ring head).
    unwind
        Bring the rotary coordinate back towards 0 on travel moves (cabled heads).
    feed_policy
        ``xy``, ``euclidean`` or ``inverse-time`` (see :mod:`gcode.rotary`).
    rotary_feed
        Speed of rotation-only moves, °/min.
    relative_e
        M83 relative E (True) or M82 absolute E.
    filament_diameter
        mm.
    bead_model
        ``rounded`` (Slic3r's rectangle with semicircular ends) or ``rectangle``.
    xy_decimals, e_decimals, angle_decimals, feed_decimals
        Precision of X/Y/Z, E, the rotary word and F. Planners must leave
        the rounding of X/Y (up to √2/2·10^-xy_decimals mm) out of their
        tolerance: see :attr:`rounding`.
    """

    letter: str = "C"
    period: float = 360.0
    angle_min: float = -math.inf
    angle_max: float = math.inf
    unwind: bool = False
    feed_policy: str = "xy"
    rotary_feed: float = 3600.0
    relative_e: bool = True
    filament_diameter: float = 1.75
    bead_model: str = "rounded"
    xy_decimals: int = 4
    e_decimals: int = 5
    angle_decimals: int = 3
    feed_decimals: int = 0

    def __post_init__(self) -> None:
        if len(self.letter) != 1 or self.letter.upper() not in "ABCUVW":
            raise InputError(f"rotary letter must be one of A B C U V W; got {self.letter!r}")
        if self.feed_policy not in _FEED_POLICIES:
            raise UnknownOptionError(f"unknown feed policy {self.feed_policy!r}; expected one "
                                     f"of: {', '.join(_FEED_POLICIES)}")
        if self.bead_model not in BEAD_MODELS:
            raise UnknownOptionError(f"unknown bead model {self.bead_model!r}; expected one "
                                     f"of: {', '.join(BEAD_MODELS)}")
        if self.period < 0 or self.angle_max < self.angle_min:
            raise InputError("rotary period must be >= 0 and angle_max >= angle_min")

    @property
    def rounding(self) -> float:
        """Largest XY displacement the rounding of coordinates can cause, mm."""
        return math.sqrt(2.0) / 2.0 * 10.0 ** -self.xy_decimals

    @property
    def rotary(self) -> bool:
        """True when rotary words are written (the nozzle is not round)."""
        return self.period > 0

    def coordinate(self, orientation: float, previous: float, *, unwind: bool = False) -> float:
        """The axis coordinate for ``orientation`` nearest ``previous`` (or 0 when unwinding).

        Raises
        ------
        ValueError
            No equivalent orientation lies within the axis limits.
        """
        ref = 0.0 if unwind else previous
        best = nearest_equivalent(orientation, ref, period=self.period or 360.0,
                                  lo=self.angle_min, hi=self.angle_max)
        if best is None:
            raise ValueError(f"orientation {orientation:.3f}° cannot be reached within the "
                             f"axis limits [{self.angle_min:g}, {self.angle_max:g}]°")
        return best


class Emitter:
    """Builds a G-code program line by line, keeping the machine state.

    Parameters
    ----------
    options
        Formatting and rotary options.
    newline
        Line terminator.

    The state (``x``, ``y``, ``z``, ``angle`` = current rotary coordinate,
    ``e`` = absolute E counter, ``feed``) starts unknown (None) except the
    angle (0) and E (0).
    """

    def __init__(self, options: WriterOptions, *, newline: str = "\n") -> None:
        self.options = options
        self.newline = newline
        self.lines: list[str] = []
        self.x: float | None = None
        self.y: float | None = None
        self.z: float | None = None
        self.angle = 0.0
        self.e = 0.0
        self._e_written = 0.0  # E counter as written (rounded), for absolute mode
        self._feed_written: str | None = None
        self.rotations = 0
        # the text of the value last formatted per kind (X, Y, Z, rotary, F): the moves
        # compare every coordinate with the current one, as written, and formatting is most
        # of a move's cost; each entry is (value, decimals, text)
        self._texts: dict[str, tuple[float, int, str]] = {}

    # ------------------------------------------------------------------ basics
    def raw(self, line: str) -> None:
        """Append a line verbatim (no state change)."""
        self.lines.append(line)

    def comment(self, text: str) -> None:
        self.lines.append(f"; {text}" if text else ";")

    def extend(self, lines: Iterable[str]) -> None:
        self.lines.extend(lines)

    def preamble(self) -> None:
        """Units, positioning and E mode (and G93 for inverse-time feed)."""
        o = self.options
        self.raw("G21 ; millimetres")
        self.raw("G90 ; absolute XYZ")
        self.raw("M83 ; relative E" if o.relative_e else "M82 ; absolute E")
        self.raw("G92 E0")
        self.e = self._e_written = 0.0
        if o.feed_policy == "inverse-time":
            self.raw("G93 ; inverse-time feed: F is 1/minutes of each move")

    def postamble(self) -> None:
        if self.options.feed_policy == "inverse-time":
            self.raw("G94 ; feed in units per minute")

    def text(self) -> str:
        """The program so far, every line terminated."""
        return "".join(line + self.newline for line in self.lines)

    # ------------------------------------------------------------------ words
    def _text(self, kind: str, value: float, decimals: int) -> str:
        """:func:`format_number`, remembering the last value of each kind."""
        last = self._texts.get(kind)
        if last is not None and last[0] == value and last[1] == decimals:
            return last[2]
        text = format_number(value, decimals)
        self._texts[kind] = (value, decimals, text)
        return text

    def _changed(self, kind: str, new: float, old: float | None, decimals: int) -> str | None:
        """The text of ``new`` if it differs from ``old``'s as written (or ``old`` is
        unknown), else None."""
        if old is not None:
            last = self._texts.get(kind)
            if last is not None and last[0] == old and last[1] == decimals:
                old_text = last[2]
            else:
                old_text = format_number(old, decimals)
        text = self._text(kind, new, decimals)
        return text if old is None or text != old_text else None

    def _xy_words(self, x: float | None, y: float | None, z: float | None) -> list[str]:
        d = self.options.xy_decimals
        words = []
        for letter, new, old in (("X", x, self.x), ("Y", y, self.y), ("Z", z, self.z)):
            if new is not None:
                text = self._changed(letter, new, old, d)
                if text is not None:
                    words.append(letter + text)
        return words

    def _feed_word(self, feed: float, length: float, rotation: float,
                   *, force: bool = False) -> list[str]:
        o = self.options
        if math.isnan(length):  # first move from an unknown place: no scaling possible
            f = feed if o.feed_policy != "inverse-time" else o.rotary_feed
        else:
            f = feed_for_move(feed, length, rotation if o.rotary else 0.0,
                              policy=o.feed_policy, rotary_feed=o.rotary_feed)
        text = self._text("F", f, o.feed_decimals if o.feed_policy != "inverse-time" else 4)
        if o.feed_policy == "inverse-time" or force or text != self._feed_written:
            self._feed_written = text
            return ["F" + text]
        return []

    def _length(self, x: float | None, y: float | None) -> float:
        """XY length of a move to (x, y), mm; NaN when the start is unknown."""
        if x is None and y is None:
            return 0.0
        if self.x is None or self.y is None:
            return math.nan
        return math.hypot((self.x if x is None else x) - self.x,
                          (self.y if y is None else y) - self.y)

    def _rotary(self, orientation: float | None, *, unwind: bool = False,
                target: float | None = None) -> tuple[list[str], float]:
        """The rotary word to ``orientation`` (its axis coordinate ``target`` when already
        known) and the step, updating the angle; none when it is the current one."""
        o = self.options
        if orientation is None or not o.rotary:
            return [], 0.0
        if target is None:
            target = o.coordinate(orientation, self.angle, unwind=unwind)
        text = self._changed("R", target, self.angle, o.angle_decimals)
        if text is None:
            return [], 0.0
        step = target - self.angle
        self.angle = target
        return [o.letter + text], step

    def _move(self, cmd: str, x, y, z, words_extra: list[str], feed: float | None,
              rotation: float, length: float, comment: str | None) -> None:
        words = [cmd, *self._xy_words(x, y, z)]
        rot = [w for w in words_extra if w[:1] == self.options.letter]
        others = [w for w in words_extra if w[:1] != self.options.letter]
        words += rot + others
        if feed is not None:
            words += self._feed_word(feed, length, rotation)
        if len(words) == 1:
            return
        line = " ".join(words)
        if comment:
            line += " ; " + comment
        self.lines.append(line)
        if x is not None:
            self.x = x
        if y is not None:
            self.y = y
        if z is not None:
            self.z = z

    # ------------------------------------------------------------------ moves
    def travel(self, x: float | None = None, y: float | None = None, *, z: float | None = None,
               feed: float, orientation: float | None = None, comment: str | None = None) -> None:
        """A non-extruding move; a change of orientation is folded into it.

        With ``unwind`` the rotary coordinate is brought to the equivalent
        nearest 0 (it only ever moves during travel).
        """
        length = self._length(x, y)
        rot, step = self._rotary(orientation, unwind=self.options.unwind)
        if step:
            self.rotations += 1
        self._move("G0" if not rot else "G1", x, y, z, rot, feed, step, length, comment)

    def rotate(self, orientation: float, *, comment: str | None = None) -> None:
        """A rotation-only move (no XY, no E) to ``orientation``."""
        rot, step = self._rotary(orientation)
        if not rot:
            return
        self.rotations += 1
        words = ["G1", *rot, *self._feed_word(0.0, 0.0, step)]
        line = " ".join(words)
        if comment:
            line += " ; " + comment
        self.lines.append(line)

    def _e_word(self, delta: float) -> str:
        o = self.options
        self.e += delta
        if o.relative_e:
            # carry the rounding error so the sum of written E equals the sum asked for
            target = round(self.e, o.e_decimals)
            text = format_number(target - self._e_written, o.e_decimals)
            self._e_written = round(self._e_written + float(text), o.e_decimals)
            return "E" + text
        self._e_written = round(self.e, o.e_decimals)
        return "E" + format_number(self._e_written, o.e_decimals)

    def extrude(self, x: float, y: float, *, feed: float, width: float | None = None,
                height: float | None = None, e: float | None = None,
                orientation: float | None = None, turn_while_moving: float | None = None,
                comment: str | None = None) -> float:
        """An extruding straight move at a constant orientation.

        Parameters
        ----------
        x, y
            End point, mm.
        feed
            XY speed, mm/min.
        width, height
            Bead width and height, mm: E is computed from the bead
            cross-section (ignored when ``e`` is given).
        e
            Filament length to feed, mm.
        orientation
            Nozzle orientation during the move, degrees; when it differs from
            the current one a rotation-only move is emitted first.
        turn_while_moving
            The turn (degrees) the caller checked with the turning footprint:
            when the axis reaches ``orientation`` by a turn no larger than it,
            the turn is made *during* the move (the rotary word goes on the
            extruding line); otherwise (near an axis limit the coordinate may
            have to go the long way round) the nozzle turns standing still.

        Returns
        -------
        float
            The E fed, mm.
        """
        o = self.options
        if self.x is None or self.y is None:
            raise ValueError("extrude() before the position is known: travel() there first")
        length = self._length(x, y)
        if e is None:
            if width is None or height is None:
                raise ValueError("extrude() needs e= or both width= and height=")
            e = length * float(e_per_mm(width, height, o.filament_diameter, model=o.bead_model))
        extra: list[str] = []
        step = 0.0
        if orientation is not None:
            o = self.options
            target = o.coordinate(orientation, self.angle) \
                if turn_while_moving is not None and o.rotary else None
            if target is not None and abs(target - self.angle) <= turn_while_moving + 1e-6:
                extra, step = self._rotary(orientation, target=target)
                if step:
                    self.rotations += 1
            else:
                self.rotate(orientation)
        self._move("G1", x, y, None, [*extra, self._e_word(e)], feed, step, length, comment)
        return e

    def arc(self, x: float, y: float, i: float, j: float, *, clockwise: bool, feed: float,
            e: float, length: float, orientation: float | None = None) -> None:
        """A G2/G3 arc; it never turns the nozzle.

        Raises
        ------
        ValueError
            ``orientation`` differs from the current one: the caller must
            linearise the arc (a rotary word on G2/G3 is never written).
        """
        if orientation is not None and self.options.rotary:
            target = self.options.coordinate(orientation, self.angle)
            if abs(target - self.angle) > 10 ** -self.options.angle_decimals:
                raise ValueError("an arc that needs to turn the nozzle must be linearised")
        d = self.options.xy_decimals
        extra = ["I" + format_number(i, d), "J" + format_number(j, d), self._e_word(e)]
        words = ["G2" if clockwise else "G3", "X" + format_number(x, d), "Y" + format_number(y, d),
                 *extra, *self._feed_word(feed, length, 0.0)]
        self.lines.append(" ".join(words))
        self.x, self.y = x, y

    def _e_only_feed(self, feed: float, length: float) -> str:
        o = self.options
        if o.feed_policy == "inverse-time":
            self._feed_written = None
            return "F" + format_number(feed / max(length, 1e-9), 4)
        self._feed_written = None  # a retraction feed must not become the XY feed
        return "F" + format_number(feed, o.feed_decimals)

    def retract(self, length: float, *, feed: float) -> None:
        """Pull the filament back by ``length`` mm (negative E, no motion), at ``feed`` mm/min."""
        if length > 0:
            self.lines.append(" ".join(["G1", self._e_word(-length),
                                        self._e_only_feed(feed, length)]))

    def unretract(self, length: float, *, feed: float) -> None:
        """Push the filament forward again by ``length`` mm."""
        if length > 0:
            self.lines.append(" ".join(["G1", self._e_word(length),
                                        self._e_only_feed(feed, length)]))


def header_lines(
    *,
    version: str,
    nozzle: str,
    machine: str,
    options: WriterOptions,
    mode: str,
    summary: Sequence[Mapping[str, float]] = (),
    notes: Sequence[str] = (),
    flavor: str | None = None,
    e_mode: str | None = None,
) -> list[str]:
    """The comment block at the top of a file printability wrote or rewrote.

    Parameters
    ----------
    version
        printability's version.
    nozzle, machine
        Their SPECs or names.
    options
        The writer options (letter, feed policy, E mode are recorded).
    mode
        ``"generated"`` or ``"postprocessed"``.
    summary
        Per layer: ``z``, ``target_area``, ``lost_area`` (mm²) and optionally
        ``dropped_moves``, ``dropped_length`` (mm), ``split_moves``.
    notes
        Free remarks, one per line.
    flavor
        The firmware flavor the file is written for (:mod:`gcode.flavors`).
    e_mode
        How the file's E words count (``relative``, ``absolute`` or ``mixed``);
        None: as the options say.
    """
    o = options
    lines = [
        f"{MARKER} {version} {mode} this file",
        f"; printability: nozzle = {nozzle}",
        f"; printability: machine = {machine}",
        f"; printability: rotary axis = {o.letter if o.rotary else 'none (round nozzle)'}"
        + (f", degrees, period {o.period:g}" if o.rotary else ""),
        (f"; printability: flavor = {flavor}, " if flavor else "; printability: ")
        + f"feed policy = {o.feed_policy}, E = "
        + (e_mode or ("relative" if o.relative_e else "absolute"))
        + f", bead model = {o.bead_model}, filament = {o.filament_diameter:g} mm",
    ]
    if summary:
        target = sum(r.get("target_area", 0.0) for r in summary)
        lost = sum(r.get("lost_area", 0.0) for r in summary)
        frac = lost / target if target > 0 else 0.0
        lines.append(f"; printability: layers = {len(summary)}, target area = {target:.3f} mm2, "
                     f"lost area = {lost:.3f} mm2 ({100 * frac:.2f} %)")
        lines.append("; printability: layer z, target mm2, lost mm2, dropped moves, "
                     "dropped mm, split moves")
        for r in summary:
            lines.append(
                f"; printability: layer {r.get('z', 0.0):.3f} {r.get('target_area', 0.0):.4f} "
                f"{r.get('lost_area', 0.0):.4f} {int(r.get('dropped_moves', 0))} "
                f"{r.get('dropped_length', 0.0):.3f} {int(r.get('split_moves', 0))}"
            )
    lines += [f"; printability: {n}" for n in notes]
    return lines
