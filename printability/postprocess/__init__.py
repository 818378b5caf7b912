"""Post-process a slicer's G-code for a nozzle on a machine with a rotary axis.

The slicer's XY paths are kept; for every extruding move of the part the
nozzle orientation is chosen so that the swept footprint stays inside the
layer's target (the MMC promise, see :mod:`printability.planning.orientation`)
and the bead width matches the slicer's planned width where possible. What
no orientation can print is cut away and reported per layer. Every line that
needs no change is kept byte for byte; the changes are:

* a rotary word (``C…``) folded into the travel move before an extrusion
  that needs another orientation (feed policy ``xy``), or a rotation-only
  line ``G1 C…`` without E inserted just before it (policy ``euclidean``,
  or no travel to fold it into). Inserted lines carry no F: the firmware
  turns at the current feed rate read as °/min, and the modal feed the
  slicer set is never disturbed;
* extruding arcs (G2/G3) of the part are linearised into G1 chords when the
  nozzle is not round (a rotary word is never put on an arc);
* a move that fits only in part is replaced by its printable pieces (with
  their share of E) joined by non-extruding moves; a move that fits nowhere
  becomes a non-extruding move. In absolute-E files a ``G92 E…`` restores
  the E coordinate the next slicer line expects;
* with ``e_policy="width"`` (default) and a non-round nozzle, E is scaled by
  the ratio of the bead cross-sections (laid width / planned width, Slic3r's
  rounded-rectangle model) where the width laid differs from the plan;
* a comment block (the nozzle, the machine, the version and the per-layer
  summary) is inserted before the first command; it also marks the file so
  it is never processed twice.

The layer target G is rebuilt from the slicer's own part extrusions exactly
as ``printability analyze`` does (:func:`printability.sources.gcode.layer_regions`:
supports, skirt, brim, wipe tower, custom/purge moves and ironing excluded;
every chord swept by a disk of half its planned width, the ``;WIDTH:``
comments or the width inverted from E). The outer perimeter's centre line is
therefore exactly w/2 from ∂G; ``tolerance`` (default 1 µm, minus the
rounding of the coordinates written) absorbs the rounding of coordinates and
of the polygonal arcs. Footprints are tested against G grown by that
tolerance. By default (``interior``) G is the object, not only its beads: the
gaps the slicer leaves inside it (sparse infill) are filled back, the holes its
outer walls trace kept (:func:`printability.sources.gcode.fill_interior`), so a
footprint may reach into a gap (inside the part) instead of turning standing
still; that target is built by GEOS per layer. With ``interior=False`` it is the
union of one convex polygon per bead (:mod:`printability.planning.beadunion`:
between G ⊕ 0.35τ and G ⊕ τ, without a GEOS overlay; built by
:mod:`printability.planning.targets`). Layers are planned in
batches, laid side by side in one plane (:mod:`printability.planning.tiles`) so
that one union and one planner call serve a batch. Non-part moves are left as
they are.

A round nozzle no larger than the one the file was sliced for (the slicer's
``nozzle_diameter``) lays the slicer's own beads, each inside G by
construction: such a file only gets the comment block. A larger round nozzle,
or any other shape, is checked move by move with its whole orifice.
"""

# The modules, by what they do:
#   options   what a run is for (PostprocessOptions), the slicer's SLIC3R_* environment
#   scan      what a file says before it is parsed: printability's marker, config comments
#   pipeline  postprocess_bytes and its stages, in the order they run
#   binary    binary G-code in, binary G-code out
#   files     postprocess_file: the memory guard, the read, the atomic write
#   results   LayerReport, PostprocessResult and the notes on them
#   memory    the memory guard's estimates
#   progress  the on_progress callback of the run under way

from printability.postprocess.files import postprocess_file
from printability.postprocess.options import PostprocessOptions, settings_from_environment
from printability.postprocess.pipeline import postprocess_bytes
from printability.postprocess.results import LayerReport, PostprocessResult
from printability.postprocess.scan import PROCESSED_KEY, already_processed

__all__ = [
    "PROCESSED_KEY",
    "LayerReport",
    "PostprocessOptions",
    "PostprocessResult",
    "already_processed",
    "postprocess_bytes",
    "postprocess_file",
    "settings_from_environment",
]
