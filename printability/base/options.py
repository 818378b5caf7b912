"""The one registry of string options.

Every string-valued option of the library and the CLI (engine names, nozzle
kinds, machine kinds, G-code flavors...) is declared here. Library code
validates with :meth:`Registry.check`; the CLI builds its help and choices from
the same objects, so the two can never disagree.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from printability.base.errors import UnknownOptionError, excerpt

__all__ = [
    "BEAD_MODELS",
    "CORNER_PIECES",
    "ENDSTOP_POLICIES",
    "ENGINES",
    "EXTRUDER_ERROR_POLICIES",
    "E_POLICIES",
    "FAULT_KINDS",
    "FEED_POLICIES",
    "FIRMWARE_PROFILES",
    "FLAVORS",
    "JOINT_KINDS",
    "MACHINE_KINDS",
    "NOZZLE_KINDS",
    "REGISTRIES",
    "SERVER_POLICIES",
    "SIM_CLOCKS",
    "SOURCE_FORMATS",
    "STREAM_MODES",
    "UNITS",
    "Registry",
]


class Registry(Mapping[str, str]):
    """A named set of valid string choices, each with a one-line description (immutable).

    Not a dataclass: the slicer plug-in's client imports this module on every export,
    and ``dataclasses`` imports ``inspect`` (a sixth of the client's start).
    """

    __slots__ = ("entries", "name")
    name: str
    entries: tuple[tuple[str, str], ...]

    def __init__(self, name: str, entries: tuple[tuple[str, str], ...]) -> None:
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "entries", tuple(entries))

    def __setattr__(self, key: str, value: object) -> None:
        raise AttributeError(f"a Registry is immutable; cannot set {key!r}")

    def __repr__(self) -> str:
        return f"Registry(name={self.name!r}, entries={self.entries!r})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Registry):
            return NotImplemented
        return (self.name, self.entries) == (other.name, other.entries)

    def __hash__(self) -> int:
        return hash((self.name, self.entries))

    def __getitem__(self, key: str) -> str:
        for k, v in self.entries:
            if k == key:
                return v
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return (k for k, _ in self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def choices(self) -> tuple[str, ...]:
        return tuple(k for k, _ in self.entries)

    def check(self, value: object) -> str:
        """Return ``value`` if it is a valid choice, else raise UnknownOptionError."""
        if isinstance(value, str):
            key = value.strip().lower()
            if key in self.choices:
                return key
        listed = ", ".join(self.choices)
        raise UnknownOptionError(
            f"unknown {self.name} {excerpt(value if isinstance(value, str) else repr(value))}; "
            f"expected one of: {listed}"
        )


def _reg(name: str, **entries: str) -> Registry:
    # Python keywords cannot hold hyphens; option names use them.
    return Registry(name, tuple((k.replace("_", "-"), v) for k, v in entries.items()))


ENGINES = _reg(
    "engine",
    auto="exact for XY with a vector-friendly nozzle, raster for rotary machines",
    exact="vector engine (shapely): affine trick for circles/ellipses, Minkowski for polygons",
    raster="grid engine with conservative rasterisation and [lo, hi] bounds",
    reference="the seed paper's literal inverse-trajectory method (slow, small inputs)",
    sampled="any machine chain: sample the joint space and test containment",
)

NOZZLE_KINDS = _reg(
    "nozzle kind",
    circle="round orifice: d=DIAMETER (or r=RADIUS)",
    ellipse="elliptical orifice: major=, minor= (full axis lengths)",
    rect="rectangular orifice: w= (along x), h= (along y)",
    polygon="any polygon: polygon:FILE.svg|FILE.txt or polygon:pts=x y;x y;...",
)

MACHINE_KINDS = _reg(
    "machine kind",
    xy="X-Y translations only; the nozzle never turns",
    ttr="X-Y translations plus a rotary axis turning the nozzle (T-T-R)",
    chain="a general planar chain of prismatic/revolute joints from a TOML file",
)

JOINT_KINDS = _reg(
    "joint kind",
    prismatic="translation along the joint's axis, mm",
    revolute="rotation about the joint's origin, degrees",
)

# the flavors themselves (what each firmware does) are gcode.flavors' classes; this registry
# holds their names for validation and help without importing the G-code package (the slicer
# plug-in's client imports this module on every export); a test keeps the two in step
FLAVORS = _reg(
    "G-code flavor",
    marlin="Marlin 2.1 or newer with AXIS4_NAME 'C' and AXIS4_ROTATES (F is the XYZ speed; "
    "degrees/min on a rotation-only move)",
    klipper="Klipper with a [manual_stepper] registered as G-code axis C (F is the XYZ speed; "
    "degrees/min on a rotation-only move; no G92 C)",
    reprap="RepRapFirmware 3 with M584 C<driver> R1 S1 in config.g (F is the XYZ speed; "
    "degrees/min on a rotation-only move)",
    generic="generic RS274 firmware that treats every axis as Euclidean (degrees count as mm "
    "in F)",
)

FEED_POLICIES = _reg(
    "feed policy",
    xy="F is the XY (tool tip) speed; rotary motion does not slow it",
    euclidean="the firmware treats degrees as mm: F is scaled so the XY speed is kept",
    inverse_time="G93 inverse-time feed: each move carries its duration",
)

EXTRUDER_ERROR_POLICIES = _reg(
    "firmware error policy",
    stop="send M112 and stop",
    cancel="stop sending and run the cancel sequence",
    ignore="log the error and keep streaming",
)

STREAM_MODES = _reg(
    "stream mode",
    auto="send-ahead when the firmware reports its free buffer (ADVANCED_OK), else ping-pong",
    ping_pong="one line at a time: send the next line only after the 'ok' of the previous one",
    send_ahead="keep several lines in flight, never more than the firmware's reported free "
    "command slots and receive buffer (needs ADVANCED_OK; ping-pong otherwise)",
)

SOURCE_FORMATS = _reg(
    "source format",
    # "3mf" is not an identifier, hence the dict below.
    gcode="sliced G-code (.gcode, .gco, .g; binary .bgcode): layers rebuilt from the "
    "extrusions",
    stl="triangle mesh (.stl, binary or ASCII; no units), sliced at a layer height",
    **{"3mf": "3MF package (.3mf; units from the file), sliced at a layer height"},
    obj="Wavefront OBJ mesh (.obj; no units), sliced at a layer height",
    svg="SVG drawing (.svg): filled shapes, one planar layer",
    slic3r_svg="Slic3r multi-layer slice SVG (slic3r --export-svg): one layer per <g>",
    dxf="DXF drawing (.dxf): closed outlines, one planar layer",
    geojson="GeoJSON (.geojson, .json): polygons; lon/lat data are projected",
    wkt="WKT text (.wkt): polygons, one planar layer",
    slices="slice-outline text (.txt): bead widths then point-count/\"x y\" curves",
)

UNITS = _reg(
    "unit",
    mm="millimetre",
    cm="centimetre (10 mm)",
    m="metre (1000 mm)",
    **{"in": "inch (25.4 mm)"},  # a Python keyword, hence the dict
    px="CSS pixel, 1/96 inch (SVG user unit)",
)

FIRMWARE_PROFILES = _reg(
    "firmware profile",
    marlin="Marlin 2.1: line numbers and checksums, Resend, plain 'ok'",
    marlin_advanced="Marlin 2.1 with ADVANCED_OK: 'ok N<line> P<planner free> B<buffer free>'",
    klipper="Klipper-like: ignores line numbers and checksums, never asks for a resend",
)

FAULT_KINDS = _reg(
    "fault kind",
    corrupt="flip a bit in a received line (the checksum catches it; a Resend follows)",
    corrupt_reply="flip a bit in the reply to a line",
    drop_line="lose a received line on the wire",
    drop_ok="never send the 'ok' of a line",
    duplicate_ok="send the 'ok' of a line twice",
    busy="send spurious 'echo:busy: processing' lines before the 'ok'",
    stall="stop answering for a while (seconds of real time)",
    disconnect="drop the link and reset: state lost, 'start' banner on reconnect",
    resend_storm="ask for a resend of the same line several times in a row",
)

ENDSTOP_POLICIES = _reg(
    "soft endstop policy",
    clamp="clamp targets to the travel limits silently (Marlin)",
    error="refuse a move that leaves the travel limits with an error (Klipper)",
)

SIM_CLOCKS = _reg(
    "simulator clock",
    sim="simulated time: the printer never waits in real time (tests, fast runs)",
    real="wall-clock time: moves, heating and dwells take as long as on the machine",
)

E_POLICIES = _reg(
    "E policy",
    width="scale the slicer's E by the bead cross-section laid at the chosen angle over the "
    "planned one",
    keep="keep the slicer's E (volume per mm as planned) whatever width the nozzle lays",
)

SERVER_POLICIES = _reg(
    "server policy",
    use="hand the run to a running `printability serve`, else run here",
    start="the same; when no server is running, start one in the background (it stops after "
    "15 idle minutes) and run here",
    off="always run here",
)

CORNER_PIECES = _reg(
    "corner-piece policy",
    drop="leave out the short pieces beside an outer wall's corners that need a turn of their "
    "own (at most one bead width each, counted as lost): a turn standing still is a full stop "
    "on real firmware",
    keep="print every piece that fits, each with its own turn (slower to print)",
)

BEAD_MODELS = _reg(
    "bead model",
    rounded="rectangle with semicircular ends, area h(w - h) + pi h^2/4 (Slic3r/PrusaSlicer)",
    rectangle="rectangle, area w h (CuraEngine)",
)

REGISTRIES: dict[str, Registry] = {
    r.name: r
    for r in (
        ENGINES,
        NOZZLE_KINDS,
        MACHINE_KINDS,
        JOINT_KINDS,
        FLAVORS,
        FEED_POLICIES,
        EXTRUDER_ERROR_POLICIES,
        STREAM_MODES,
        SOURCE_FORMATS,
        UNITS,
        FIRMWARE_PROFILES,
        FAULT_KINDS,
        ENDSTOP_POLICIES,
        SIM_CLOCKS,
        SERVER_POLICIES,
        CORNER_PIECES,
    )
}
