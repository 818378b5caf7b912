"""Layers: the targets G of a sliced part, bottom to top.

Every layer source (G-code, meshes, SVG/DXF/GeoJSON/WKT, slice files) returns a
:class:`LayerStack`; the analysis, the report and the G-code generator consume
it. A single 2-D outline is a stack of one layer.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from shapely.geometry import MultiPolygon

from printability.errors import InputError

__all__ = ["Layer", "LayerStack"]


@dataclass(frozen=True)
class Layer:
    """One layer: its target region G at height ``z`` (top of the layer), mm.

    Attributes
    ----------
    z
        Height of the layer's top, mm (the Z a slicer prints it at).
    height
        Layer thickness, mm (0 for a purely planar input).
    region
        The target G, validated (see :func:`printability.model.geometry.as_region`).
    index
        0-based position in the stack.
    meta
        Source-specific facts (slicer feature widths, original layer number...).
    """

    z: float
    height: float
    region: MultiPolygon
    index: int = 0
    meta: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def area(self) -> float:
        return float(self.region.area)


@dataclass(frozen=True)
class LayerStack(Sequence[Layer]):
    """Layers of one part, ordered by ``z``.

    Attributes
    ----------
    layers
        The layers.
    source
        Where they came from (file path, or a description).
    units
        Always ``"mm"`` once loaded (sources convert).
    meta
        Source facts: slicer name and settings, scale applied, projection...
    """

    layers: tuple[Layer, ...]
    source: str = ""
    units: str = "mm"
    meta: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if not self.layers:
            raise InputError(f"{self.source or 'input'}: no layer with a printable region")
        zs = [layer.z for layer in self.layers]
        if zs != sorted(zs):
            raise InputError(f"{self.source or 'input'}: layers are not ordered by z")

    def __getitem__(self, i):  # type: ignore[override]
        return self.layers[i]

    def __len__(self) -> int:
        return len(self.layers)

    def __iter__(self) -> Iterator[Layer]:
        return iter(self.layers)

    @property
    def is_planar(self) -> bool:
        """True for a single layer of zero height (an outline, not a part)."""
        return len(self.layers) == 1 and self.layers[0].height == 0.0

    @property
    def volume(self) -> float:
        """Σ area·height, mm³."""
        return float(sum(layer.area * layer.height for layer in self.layers))
