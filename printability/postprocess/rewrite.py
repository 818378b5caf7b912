"""The rewrite pass of the post-processor: copy the slicer's file, editing the planned moves.

Given the plan (an orientation per chord, the printable pieces of split moves, the
width laid), :func:`rewrite` copies the G-code: runs of lines that need no change
are copied as slices of the input, byte for byte; a move that only turns gains a
rotary word (or a rotation-only line before it); a move whose E changes is edited
in place (with ``G92 E…`` after it in absolute-E files); arcs and split moves
become new ``G1`` lines, a turn into a piece riding on the piece's line where the plan
made it while moving (``Plan.piece_fold``), else on the line to the piece's start when
there is one (nothing is deposited there), else on a line of its own. See
:mod:`printability.postprocess` for what each change means to the print.

Two passes write the same bytes: :func:`rewrite_reference`, in Python
(:mod:`printability.postprocess._rewrite_reference`), and the compiled one of
:mod:`printability.postprocess._rewrite_kernel` that :func:`rewrite` runs (about 6× faster on the
calibration cube and 7× on Benchy), which hands what it cannot write exactly to the
reference. Both read the moves :func:`~printability.postprocess._rewrite_events.scan_events` finds
(:mod:`printability.postprocess._rewrite_events`, with the records they take).
"""

from __future__ import annotations

from printability.postprocess._rewrite_events import (
    ChordPlan,
    RewriteOutput,
    SlicerFile,
    WriteSettings,
    e_scale,
    e_scales,
    eol_of,
    first_command_line,
    planned_turns,
    scan_events,
)
from printability.postprocess._rewrite_reference import rewrite_reference

__all__ = ["ChordPlan", "RewriteOutput", "SlicerFile", "WriteSettings", "e_scale", "e_scales",
           "eol_of", "first_command_line", "planned_turns", "rewrite", "rewrite_reference"]


def rewrite(src: SlicerFile, plan: ChordPlan,
            settings: WriteSettings) -> tuple[RewriteOutput, dict[int, int]]:
    """Copy the file, rewriting the part extrusions that need it.

    The compiled pass of :mod:`printability.postprocess._rewrite_kernel` writes the bytes
    :func:`rewrite_reference` writes; what it declines (numbers or lines outside
    the range where it is exact, see there) goes to the reference.

    Parameters
    ----------
    src
        The slicer's file: its bytes, its parse and its moves.
    plan
        Per chord: the move, the angle, the fold, the width laid and planned, the pieces
        of split moves (``piece_rows``: arrays ``(chord, t0, t1, angle)`` by chord, when
        known; ``piece_fold`` per such row True where the turn into the piece is made
        during it, :attr:`~printability.planning.orientation.Plan.piece_fold`).
    settings
        The writer's options, whether the nozzle turns, the E policy and the nozzle.

    Returns
    -------
    The output and the rotary words per layer.
    """
    from printability.postprocess._rewrite_kernel import rewrite_compiled

    ev = scan_events(src, plan, settings)
    done = rewrite_compiled(src, plan, settings, ev) if ev.ev_line.size \
        else None
    return done if done is not None else rewrite_reference(src, plan, settings, events=ev)
