"""The slicer G-code samples of ../shared/data/gcode (see its SOURCES.md), one list for every
test module that runs them all."""

from __future__ import annotations

__all__ = ["GCODE_SAMPLES"]

GCODE_SAMPLES = (
    "bambustudio_1.10_klipper_arcs.gcode",
    "cura_5.9.1_marlin.gcode",
    "orcaslicer_2.3.0b2_klipper_arcs.gcode",
    "prusaslicer_2.7.4_marlin2_arcs.gcode",
    "prusaslicer_2.7.4_spiral_vase.gcode",
    "slic3rpe_1.33_arcwelder_benchy.gcode",
)
