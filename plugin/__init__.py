"""Slicer integrations: thin adapters around ``printability postprocess``.

* :mod:`plugin.prusaslicer` — the post-processing entry point for PrusaSlicer,
  SuperSlicer and OrcaSlicer (console script ``printability-postprocess``);
* ``plugin/cura/PrintabilityRotary.py`` — a Cura PostProcessingPlugin script
  that calls the CLI (Cura's bundled Python lacks our dependencies), with its
  settings in ``plugin/cura/printability_rotary.json``.
"""
