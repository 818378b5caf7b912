"""Motion synthesis (docs/design.md §3): what the nozzle does, move by move.

* :mod:`printability.motion.orientation` — the MMC-safe nozzle orientation of
  every extruding move (bead width as planned, turning least), splitting what
  no orientation can print;
* :mod:`printability.motion.toolpaths` — perimeters, infill and their order
  (networkx) for ``printability generate``;
* :mod:`printability.motion.check` — an independent check of what a G-code
  file deposits against each layer's target;
* :mod:`printability.motion.tiles` — layers laid side by side in one plane, so
  that the post-processor plans a batch of layers against one target.
"""
