"""Motion synthesis (docs/design.md §3): what the nozzle does, move by move.

* :mod:`printability.planning.orientation` — the MMC-safe nozzle orientation of
  every extruding move (bead width as planned, turning least), splitting what
  no orientation can print;
* :mod:`printability.planning.toolpaths` — perimeters, infill and their order
  (networkx) for ``printability generate``;
* :mod:`printability.planning.check` — an independent check of what a G-code
  file deposits against each layer's target;
* :mod:`printability.planning.tiles` — layers laid side by side in one plane, so
  that the post-processor plans a batch of layers against one target;
* :mod:`printability.planning.targets` — the layer targets the post-processor plans
  against, built from the slicer's own beads.
"""
