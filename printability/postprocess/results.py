"""What a run did: :class:`LayerReport` per layer, :class:`PostprocessResult` per file, and
the notes on them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcode.printtime import PrintTime, format_duration


@dataclass(frozen=True)
class LayerReport:
    """What post-processing did to one layer (lengths in mm, areas in mm²)."""

    index: int
    z: float
    target_area: float
    moves: int
    turned: int
    split_moves: int
    dropped_moves: int
    dropped_length: float
    dropped_area: float
    printed_length: float


@dataclass(frozen=True)
class PostprocessResult:
    """Outcome of a post-processing run."""

    path: str
    output: str
    already_processed: bool
    # print_time_in / print_time_out: seconds Klipper's planner takes for the slicer's file
    # and for the rewritten one with the machine's limits (gcode.printtime), None when not
    # estimated; filament_in / filament_out: mm of filament the extruding moves push, before
    # and after; binary: what the binary G-code's G-code blocks are (compression, encoding),
    # None for text G-code
    lines_in: int
    lines_out: int
    changed_lines: int
    inserted_lines: int
    rotary_words: int
    layers: tuple[LayerReport, ...]
    elapsed: float
    nozzle: str
    machine: str
    notes: tuple[str, ...] = ()
    print_time_in: float | None = None
    print_time_out: float | None = None
    filament_in: float | None = None
    filament_out: float | None = None
    binary: str | None = None

    @property
    def dropped_moves(self) -> int:
        return sum(r.dropped_moves for r in self.layers)

    @property
    def split_moves(self) -> int:
        return sum(r.split_moves for r in self.layers)

    @property
    def dropped_length(self) -> float:
        return sum(r.dropped_length for r in self.layers)


def unchanged_result(path: str, n_lines: int, *, binary: str | None = None
                     ) -> PostprocessResult:
    """The result for a file printability already post-processed: left as it is."""
    return PostprocessResult(path, path, True, n_lines, n_lines, 0, 0, 0, (), 0.0, "", "",
                             ("already post-processed by printability: left unchanged",),
                             binary=binary)


def layer_reports(g, layers, areas, idx, counts, lay_of, plan, seg_len, widths
                  ) -> list[LayerReport]:
    """What the plan of a batch did to each of its layers (``idx``: the batch's chords,
    ``counts`` per layer, ``lay_of`` the layer of each within the batch)."""
    from printability.planning.orientation import piece_losses

    n = len(layers)
    split = np.zeros(n, np.int64)
    dropped = np.zeros(n, np.int64)
    d_len = np.zeros(n)
    d_area = np.zeros(n)
    if plan is not None and plan.pieces:
        keys = np.fromiter(plan.pieces, dtype=np.int64, count=len(plan.pieces))
        rows = plan.piece_rows
        row_move = np.asarray(rows[0], np.int64)
        split, dropped, d_len, d_area = piece_losses(
            keys, np.searchsorted(row_move, keys, "left"),
            np.searchsorted(row_move, keys, "right"), np.asarray(rows[1], float),
            np.asarray(rows[2], float), np.asarray(lay_of, np.int64),
            np.asarray(seg_len[idx[keys]], float), np.asarray(widths[idx[keys]], float), n)
    d_len = d_len.tolist()
    d_area = d_area.tolist()
    starts = np.concatenate([[0], np.cumsum(counts)])
    return [LayerReport(
        index=k, z=float(g.layers["z"][k]), target_area=areas[j], moves=int(counts[j]),
        turned=0, split_moves=int(split[j]), dropped_moves=int(dropped[j]),
        dropped_length=d_len[j], dropped_area=d_area[j],
        printed_length=float(seg_len[idx[starts[j]:starts[j + 1]]].sum()) - d_len[j],
    ) for j, k in enumerate(layers)]


def layer_summary(reports: list[LayerReport]) -> list[dict[str, float]]:
    """The per-layer summary the comment block lists."""
    return [{"z": r.z, "target_area": r.target_area, "lost_area": r.dropped_area,
             "dropped_moves": r.dropped_moves, "dropped_length": r.dropped_length,
             "split_moves": r.split_moves} for r in reports]


def print_time_note(t_in: float, out: PrintTime) -> str:
    """One line on the print time before and after, and what the turns cost."""
    text = (f"estimated print time on the firmware's planner (Klipper's look-ahead, the "
            f"machine's [planner] limits): slicer's file {format_duration(t_in)}, this file "
            f"{format_duration(out.total)}")
    if t_in > 0:
        text += f" ({out.total / t_in:.2f}x)"
    if out.rotation_only:
        text += (f"; {out.rotation_only} rotation-only moves take "
                 f"{format_duration(out.rotation_only_time)}, each a full stop")
    return text


def filament(moves: np.ndarray) -> float:
    """mm of filament the extruding moves push."""
    return float(moves["e"][moves["is_extrusion"]].sum())
