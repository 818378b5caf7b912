"""The real Klipper host (klippy) in the loop: run a G-code file through Klipper's own G-code
parser and motion planner in batch mode, and read back what it said and how long it planned.

``scripts/build-klipper`` builds Klipper (a writable copy of ``../shared/firmware/klipper``, the
Linux-host MCU's data dictionary, a venv of its own) into ``build/klipper/``. :func:`run_klipper`
then runs ``klippy.py printer.cfg -i FILE -o /dev/null -d klipper.dict`` in that venv, through a
small launcher that hooks into the running klippy (it changes no file of Klipper's; the build
fixes one memory-safety bug of its C helper, see ``scripts/build-klipper``) to record:

- every response to every line of the file, with the line's number: ``!!`` errors (``Move out
  of range``, ``Must home axis first``, a malformed parameter...), ``Unknown command``, and the
  other ``//`` messages;
- the planned print time: the toolhead's print time when the file ends minus its print time when
  the first timed command (a move or a dwell) was queued, i.e. the seconds of motion and dwell
  Klipper's look-ahead planner scheduled for the whole file. In batch mode the MCU clock is a
  dummy (``estimated_print_time`` is 0), so this is deterministic and independent of how fast
  the host ran. Heating waits (M109/M190) take no time in batch mode;
- every planned move (its line, start time, accel/cruise/decel times and velocities), so that
  junction speeds and full stops can be read.

Two deliberate differences from a printer printing the file from Klipper's virtual SD card:
batch mode stops at the first error, the launcher keeps going (as a host streaming the file over
serial would see it) so that one run lists every error; and Klipper silently drops G-code words
it has no use for (an unregistered ``C`` word on G1, ``G92 C``, a ``C`` on G2/G3), so the runner
scans the file itself for those (:func:`scan_ignored_words`).

A rotary nozzle axis is a ``[manual_stepper c]`` that klippy maps to a G-code letter only on the
command ``MANUAL_STEPPER STEPPER=c GCODE_AXIS=C LIMIT_VELOCITY= LIMIT_ACCEL=
INSTANTANEOUS_CORNER_VELOCITY=``. :func:`printer_cfg` writes that command into the config as a
``# printability-axis:`` comment, and :func:`run_klipper` sends it before the file unless the
file registers an axis itself (a real printer does it in its start G-code or a macro; the
ignored-word scan follows the axes klippy actually registered, wherever that happened).

The config is written by :mod:`simulators.klipper_cfg` and the ignored-word scan is
:mod:`simulators.klipper_words` (both re-exported here). These modules import nothing else from
the project (they are a test and benchmark instrument).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simulators.klipper_cfg import START_END_MACROS, cfg_preamble, printer_cfg
from simulators.klipper_words import IgnoredWord, scan_ignored_words

__all__ = [
    "MOVE_DTYPE",
    "START_END_MACROS",
    "IgnoredWord",
    "KlipperError",
    "KlipperNotBuiltError",
    "KlipperRun",
    "klipper_available",
    "klipper_build_dir",
    "printer_cfg",
    "run_klipper",
    "scan_ignored_words",
]

ROOT = Path(__file__).resolve().parents[1]

#: Where ``scripts/build-klipper`` puts its build (``PRINTABILITY_KLIPPER_BUILD`` overrides).
DEFAULT_BUILD_DIR = ROOT / "build" / "klipper"

#: One planned move (:attr:`KlipperRun.moves`). Times in s from the start of the print
#: (:attr:`KlipperRun.print_time` is measured from the same origin); ``distance`` in mm for a
#: move with X/Y/Z motion, else (``kinematic`` False: extrude-only or rotation-only) in the
#: units of the axis that moves most (mm of E, degrees of a rotary axis), and the velocities and
#: ``accel`` in those units per s and s²; ``x y z e`` the end position in mm; ``rotary`` the end
#: position of the first registered extra axis (degrees; NaN when none is registered); ``line``
#: the line of the file the move came from (0: the runner's preamble); ``homing`` True for the
#: moves a G28 made through the planner (its back-off moves; its homing moves proper run outside
#: it and are not listed).
MOVE_DTYPE = np.dtype([
    ("line", np.int64), ("start", np.float64), ("duration", np.float64),
    ("accel_t", np.float64), ("cruise_t", np.float64), ("decel_t", np.float64),
    ("distance", np.float64), ("start_v", np.float64), ("cruise_v", np.float64),
    ("end_v", np.float64), ("accel", np.float64), ("kinematic", np.bool_),
    ("x", np.float64), ("y", np.float64), ("z", np.float64), ("e", np.float64),
    ("rotary", np.float64), ("homing", np.bool_),
])
_RAW_FIELDS = 17    # doubles per move written by the launcher (see _LAUNCHER: record())

class KlipperError(RuntimeError):
    """Klipper could not run the file (no build, a config it refused, a crash or a timeout)."""


class KlipperNotBuiltError(KlipperError):
    """``scripts/build-klipper`` has not been run (or its build is incomplete)."""


@dataclass(frozen=True)
class KlipperRun:
    """What klippy made of one G-code file (:func:`run_klipper`).

    Attributes
    ----------
    print_time : float
        Seconds Klipper's planner scheduled for the whole file: from the start of the first move
        or dwell to the end of the last one: moves, homing, and :attr:`wait_time` (heating
        waits take no time in batch mode).
    motion_time : float
        Sum of the durations of the planned moves, s, G28's excluded.
    homing_time : float
        The part of ``print_time`` spent in G28, s. Batch mode has no endstop that triggers, so
        Klipper plans each homing move over 1.5 times the axis's travel (about 50 s for the
        default :func:`printer_cfg`); subtract it for the time of the print proper.
    errors : tuple of (int, str)
        ``(line, message)`` for every ``!!`` response: errors such as ``Move out of range:
        ...`` or ``Must home axis first: ...``. Line 0 is the runner's preamble.
    unknown_commands : tuple of (int, str)
        ``(line, command)`` for every ``Unknown command`` Klipper reported.
    ignored_words : tuple of IgnoredWord
        Words Klipper silently dropped (found by :func:`scan_ignored_words`).
    messages : tuple of (int, str)
        Every other response (``//`` informational lines, M114/M105 reports), ``ok`` excluded.
    moves : numpy.ndarray
        Planned moves, in order, with dtype :data:`MOVE_DTYPE` (homing moves are not included).
    lines : int
        Lines of the file klippy processed (all of them when ``completed``).
    completed : bool
        klippy read the whole file and exited normally (no shutdown).
    shutdown : str or None
        Klipper's shutdown message, if it shut down (M112, an internal error).
    exit_code : int
        klippy's exit status.
    axes : str
        The G-code axis letters registered for the run (``XYZE`` plus any extra axis).
    wall_time : float
        Seconds the run took (klippy start, file, exit).
    log : str
        klippy's log.
    """

    print_time: float
    motion_time: float
    homing_time: float
    errors: tuple[tuple[int, str], ...]
    unknown_commands: tuple[tuple[int, str], ...]
    ignored_words: tuple[IgnoredWord, ...]
    messages: tuple[tuple[int, str], ...]
    moves: np.ndarray = field(repr=False)
    lines: int
    completed: bool
    shutdown: str | None
    exit_code: int
    axes: str
    wall_time: float
    log: str = field(repr=False)

    @property
    def wait_time(self) -> float:
        """Seconds of ``print_time`` in neither moves nor homing: G4 dwells, the 0.1 s Klipper
        waits before M84/M18 turns motors off, and the ~0.25 s restart of the toolhead's buffer
        after a command that flushes step generation (``SET_KINEMATIC_POSITION``,
        ``MANUAL_STEPPER``, M84)."""
        return self.print_time - self.motion_time - self.homing_time

    @property
    def ok(self) -> bool:
        """True when the file ran to its end with no error, unknown command or ignored word."""
        return (self.completed and not self.errors and not self.unknown_commands
                and not self.ignored_words)


# --------------------------------------------------------------------------- the build

def klipper_build_dir() -> Path | None:
    """The Klipper build made by ``scripts/build-klipper``, or None when there is none.

    Returns
    -------
    pathlib.Path or None
        ``build/klipper`` of this repository (or ``$PRINTABILITY_KLIPPER_BUILD``) when it holds
        a complete build: the venv's Python, klippy with its compiled C helper, and the MCU
        data dictionary.
    """
    build = Path(os.environ.get("PRINTABILITY_KLIPPER_BUILD", DEFAULT_BUILD_DIR))
    needed = (build / "venv" / "bin" / "python", build / "src" / "klippy" / "klippy.py",
              build / "src" / "klippy" / "chelper" / "c_helper.so",
              build / "src" / "out" / "klipper.dict", build / "src.stamp")
    return build if all(p.exists() for p in needed) else None


def klipper_available() -> bool:
    """True when :func:`run_klipper` can run (``scripts/build-klipper`` has built Klipper)."""
    return klipper_build_dir() is not None


def _require_build() -> Path:
    build = klipper_build_dir()
    if build is None:
        where = os.environ.get("PRINTABILITY_KLIPPER_BUILD", str(DEFAULT_BUILD_DIR))
        raise KlipperNotBuiltError(
            f"Klipper is not built: no complete build at {where} (a venv with klippy's "
            "requirements, klippy with its compiled C helper, and the Linux MCU data dictionary "
            "out/klipper.dict). Run scripts/build-klipper from the repository root (it copies "
            "../shared/firmware/klipper, or $PRINTABILITY_KLIPPER_SRC, and needs only Python 3, "
            "pip, gcc and make; scripts/test runs it), or point PRINTABILITY_KLIPPER_BUILD at "
            "an existing build.")
    return build


# --------------------------------------------------------------------------- the run

# Runs inside klippy's venv: hooks into klippy (no file of Klipper's changes) and writes what it
# saw. argv: klippy dir, result path, number of preamble lines, '--', klippy's own arguments.
_LAUNCHER = r'''
import sys, os, json, logging, array, math
klippy_dir, result_path, n_pre = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.argv = [os.path.join(klippy_dir, "klippy.py")] + sys.argv[5:]
sys.path.insert(0, klippy_dir)
import util
# klippy asks git for its version: the build copy lives inside another git repository
def _version(from_file=True):
    return {"version": util.get_version_from_file(klippy_dir), "file_status": [],
            "branch": "?", "remote": "?", "url": "?"}
util.get_git_version = _version
import klippy

class Probe:
    def __init__(self, printer):
        self.printer = printer
        self.gcode = gcode = printer.lookup_object("gcode")
        self.toolhead = None
        self.line = 0
        self.responses = []
        self.moves = array.array("d")
        self.start_time = None
        self.end_time = None
        self.motion_time = 0.
        self.homing_time = 0.
        self.in_g28 = False
        self.ready = False
        self.shutdown = None
        self.written = False
        gcode.register_output_handler(self.on_response)
        printer.register_event_handler("klippy:ready", self.on_ready)
        printer.register_event_handler("klippy:shutdown", self.on_shutdown)
        printer.register_event_handler("klippy:disconnect", self.write)
        printer.register_event_handler("toolhead:sync_print_time", self.on_sync)
        printer.register_event_handler("gcode:debuginput_exit", self.on_exit)
        printer.register_event_handler("toolhead:update_extra_axes", self.on_axes)
        self.axis_changes = []
        self.axes_at_start = ""
    def on_ready(self):
        self.ready = True
        gcode, toolhead = self.gcode, self.printer.lookup_object("toolhead")
        self.toolhead = toolhead
        self.gcode_move = self.printer.lookup_object("gcode_move")
        self.axes_at_start = "".join(self.gcode_move.axis_map)
        orig_process = gcode._process_commands
        def process(commands, need_ack=True):
            if not need_ack:       # a macro's script: its lines belong to the calling line
                return orig_process(commands, need_ack)
            for line in commands:  # the file: one line at a time, counting
                self.line += 1
                orig_process([line], True)
        gcode._process_commands = process
        # Batch mode exits on the first error (gcode.py _respond_error); keep going, as a host
        # streaming the file would, to list every error in one run
        def respond_error(msg):
            logging.warning(msg)
            lines = msg.strip().split("\n")
            if len(lines) > 1:
                gcode.respond_info("\n".join(lines), log=False)
            gcode.respond_raw("!! %s" % (lines[0].strip(),))
        gcode._respond_error = respond_error
        # Batch mode has no endstops that trigger: homing runs each axis 1.5 times its travel.
        # Its share of the print time is told apart
        handlers = gcode.ready_gcode_handlers
        orig_g28 = handlers.get("G28")
        if orig_g28 is not None:
            def g28(gcmd):
                t0 = toolhead.get_last_move_time()
                self.in_g28 = True
                try:
                    orig_g28(gcmd)
                finally:
                    self.in_g28 = False
                    if not self.printer.is_shutdown():
                        self.homing_time += toolhead.get_last_move_time() - t0
            handlers["G28"] = g28
        lookahead = toolhead.lookahead
        orig_add = lookahead.add_move
        def add_move(move):
            line, homing = self.line, self.in_g28
            move.timing_callbacks.append(lambda t, m=move: self.record(m, t, line, homing))
            return orig_add(move)
        lookahead.add_move = add_move
    def record(self, m, end, line, homing):
        if not homing:
            self.motion_time += m.accel_t + m.cruise_t + m.decel_t
        ep = m.end_pos
        self.moves.extend((line, end, m.accel_t, m.cruise_t, m.decel_t, m.move_d, m.start_v,
                           m.cruise_v, m.end_v, m.accel, float(m.is_kinematic_move),
                           ep[0], ep[1], ep[2], ep[3], ep[4] if len(ep) > 4 else math.nan,
                           float(homing)))
    def on_axes(self):
        # gcode_move's handler for this event ran first (registered before us): its axis_map
        # is the new one
        self.axis_changes.append((self.line, "".join(self.gcode_move.axis_map)))
    def on_sync(self, curtime, est_print_time, print_time):
        if self.start_time is None:
            self.start_time = print_time
    def on_response(self, msg):
        if msg != "ok":
            self.responses.append((self.line, msg))
    def on_shutdown(self):
        self.shutdown = self.printer.get_state_message()[0]
    def on_exit(self):
        if self.end_time is None and not self.printer.is_shutdown():
            self.end_time = self.toolhead.get_last_move_time()
        return True
    def write(self):
        if self.written:
            return
        self.written = True
        if self.end_time is None and self.toolhead is not None:
            self.end_time = self.toolhead.print_time
        with open(result_path + ".moves", "wb") as f:
            self.moves.tofile(f)
        res = {"ready": self.ready, "lines": self.line, "preamble": n_pre,
               "start_time": self.start_time, "end_time": self.end_time,
               "motion_time": self.motion_time,
               "homing_time": self.homing_time, "responses": self.responses,
               "shutdown": self.shutdown, "axes_at_start": self.axes_at_start,
               "axis_changes": self.axis_changes,
               "axes": "".join(self.gcode_move.axis_map) if self.ready else ""}
        with open(result_path + ".tmp", "w") as f:
            json.dump(res, f)
        os.replace(result_path + ".tmp", result_path)

_read_config = klippy.Printer._read_config
def read_config(self):
    _read_config(self)
    Probe(self)
klippy.Printer._read_config = read_config
klippy.main()
'''


def _as_bytes(gcode: str | os.PathLike[str] | bytes) -> bytes:
    if isinstance(gcode, bytes):
        return gcode
    return Path(gcode).read_bytes()


def run_klipper(
    gcode: str | os.PathLike[str] | bytes,
    *,
    cfg: str,
    register_axes: bool | None = None,
    timeout: float = 900.0,
    keep_dir: str | os.PathLike[str] | None = None,
) -> KlipperRun:
    """Run a G-code file through klippy in batch mode and report what it made of it.

    Parameters
    ----------
    gcode : path or bytes
        The G-code file (a path), or its content (bytes).
    cfg : str
        A Klipper config, e.g. from :func:`printer_cfg`; the commands in its
        ``# printability-axis:`` and ``# printability-preamble:`` comments are sent before the
        file (their responses are reported at line 0).
    register_axes : bool or None
        Send the config's ``MANUAL_STEPPER ... GCODE_AXIS=`` registration before the file: None
        (default) unless the file registers an axis itself; True always; False never (a macro of
        ``cfg`` does it, for example).
    timeout : float
        Seconds before klippy is stopped and :class:`KlipperError` raised.
    keep_dir : path or None
        Write klippy's inputs and outputs (``printer.cfg``, ``input.gcode``, ``klippy.log``,
        ``result.json``) there and keep them; by default a temporary folder is removed.

    Returns
    -------
    KlipperRun

    Raises
    ------
    KlipperNotBuiltError
        ``scripts/build-klipper`` has not been run.
    KlipperError
        klippy refused the config, crashed before reading the file, or timed out.
    """
    build = _require_build()
    data = _as_bytes(gcode)
    registrations, preamble = cfg_preamble(cfg)
    file_registers = re.search(rb"(?im)^\s*(?:N\d+\s+)?MANUAL_STEPPER\b[^;\n]*GCODE_AXIS=",
                               data) is not None
    if register_axes is None:
        register_axes = not file_registers
    if register_axes:
        preamble = [*registrations, *preamble]
    if keep_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="klipper-batch-")
        work = Path(tmp.name)
    else:
        tmp = None
        work = Path(keep_dir)
        work.mkdir(parents=True, exist_ok=True)
    try:
        return _run(build, work, cfg, preamble, data, timeout)
    finally:
        if tmp is not None:
            tmp.cleanup()


def _run(build: Path, work: Path, cfg: str, preamble: list[str], data: bytes,
         timeout: float) -> KlipperRun:
    cfg_path, gcode_path = work / "printer.cfg", work / "input.gcode"
    log_path, result = work / "klippy.log", work / "result.json"
    for p in (result, Path(str(result) + ".moves")):
        p.unlink(missing_ok=True)
    cfg_path.write_text(cfg)
    with open(gcode_path, "wb") as f:
        f.write("".join(c + "\n" for c in preamble).encode())
        f.write(data)
        # klippy drops a last line that has no newline (gcode.py keeps it as partial input)
        if data and not data.endswith(b"\n"):
            f.write(b"\n")
    klippy_dir = build / "src" / "klippy"
    cmd = [str(build / "venv" / "bin" / "python"), "-c", _LAUNCHER, str(klippy_dir),
           str(result), str(len(preamble)), "--", str(cfg_path), "-i", str(gcode_path),
           "-o", os.devnull, "-d", str(build / "src" / "out" / "klipper.dict")]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    t0 = time.perf_counter()
    with open(log_path, "wb") as log:
        try:
            proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=log,
                                  stderr=subprocess.STDOUT, env=env, timeout=timeout,
                                  check=False)
        except subprocess.TimeoutExpired:
            raise KlipperError(
                f"klippy did not finish the file within {timeout:g} s; its log is "
                f"{_tail(log_path)}") from None
    wall = time.perf_counter() - t0
    log_text = log_path.read_text(errors="replace")
    if not result.exists():
        raise KlipperError(f"klippy exited with status {proc.returncode} without a result; "
                           f"its log ends: {_tail(log_path)}")
    res = json.loads(result.read_text())
    if not res["ready"]:
        raise KlipperError(f"klippy did not get ready (a config it refused?); its log ends: "
                           f"{_tail(log_path)}")
    n_pre = res["preamble"]
    raw = np.fromfile(str(result) + ".moves", dtype=np.float64).reshape(-1, _RAW_FIELDS)
    start = res["start_time"]
    moves = _moves(raw, n_pre, start)
    errors, unknown, messages = [], [], []
    for n, text in res["responses"]:
        line = max(0, n - n_pre)
        for part in text.split("\n"):
            if part.startswith("!! "):
                errors.append((line, part[3:]))
            elif part.startswith('// Unknown command:"') and part.endswith('"'):
                unknown.append((line, part[len('// Unknown command:"'):-1]))
            elif not part.startswith("// Klipper state:"):
                messages.append((line, part[3:] if part.startswith("// ") else part))
    print_time = 0.0 if start is None else res["end_time"] - start
    # the words klippy dropped, with the axes it had registered at each line (macros included)
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    ignored = scan_ignored_words(lines, axes=res["axes_at_start"], axis_changes=[
        (max(0, n - n_pre), letters) for n, letters in res["axis_changes"]])
    return KlipperRun(
        print_time=print_time, motion_time=res["motion_time"],
        homing_time=res["homing_time"], errors=tuple(errors),
        unknown_commands=tuple(unknown), ignored_words=tuple(ignored),
        messages=tuple(messages), moves=moves, lines=max(0, res["lines"] - n_pre),
        completed=proc.returncode == 0 and res["shutdown"] is None, shutdown=res["shutdown"],
        exit_code=proc.returncode, axes=res["axes"], wall_time=wall, log=log_text)


def _moves(raw: np.ndarray, n_pre: int, start: float | None) -> np.ndarray:
    moves = np.zeros(len(raw), dtype=MOVE_DTYPE)
    if not len(raw):
        return moves
    duration = raw[:, 2] + raw[:, 3] + raw[:, 4]
    moves["line"] = np.maximum(raw[:, 0].astype(np.int64) - n_pre, 0)
    moves["start"] = raw[:, 1] - duration - (start or 0.0)
    moves["duration"] = duration
    for i, name in enumerate(("accel_t", "cruise_t", "decel_t", "distance", "start_v",
                              "cruise_v", "end_v", "accel"), 2):
        moves[name] = raw[:, i]
    moves["kinematic"] = raw[:, 10] != 0
    for i, name in enumerate(("x", "y", "z", "e", "rotary"), 11):
        moves[name] = raw[:, i]
    moves["homing"] = raw[:, 16] != 0
    return moves


def _tail(path: Path, n: int = 15) -> str:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return "(no log)"
    return " | ".join(line.strip() for line in lines[-n:]) or "(empty)"

