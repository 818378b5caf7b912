"""Choosing the layers of a part to analyse (``--layers``)."""

from __future__ import annotations

from dataclasses import replace

from printability.errors import InputError
from printability.model.layers import LayerStack

__all__ = ["select_layers"]


def select_layers(layers: LayerStack, spec: str) -> LayerStack:
    """Keep some layers of a stack, by 0-based index.

    Parameters
    ----------
    layers
        The part.
    spec
        Comma-separated items, each an index ``7``, an inclusive range ``3-9`` or a
        Python-style slice ``START:STOP[:STEP]`` (ends may be omitted, ``::10`` is
        every tenth layer). Negative indices count from the top.

    Returns
    -------
    LayerStack
        The chosen layers in z order, renumbered from 0; each keeps its index in
        the full stack as ``meta["source_index"]``.

    Raises
    ------
    InputError
        The spec cannot be read or selects no layer.
    """
    n = len(layers)
    chosen: set[int] = set()

    def bad(why: str) -> InputError:
        return InputError(f"--layers {spec!r}: {why}; expected indices, ranges A-B or slices "
                          f"START:STOP:STEP of the {n} layer(s) of {layers.source or 'the input'}"
                          f" (0 is the bottom layer)")

    def num(v: str, item: str) -> int:
        try:
            return int(v)
        except ValueError:
            raise bad(f"{item!r} is not a number, range or slice") from None

    def check(i: int) -> int:
        if not -n <= i < n:
            raise bad(f"layer {i} does not exist")
        return i % n

    for item in (t.strip() for t in spec.split(",")):
        if ":" in item:
            parts = [num(v, item) if v.strip() else None for v in item.split(":")]
            if len(parts) > 3 or (len(parts) == 3 and parts[2] == 0):
                raise bad(f"{item!r} is not a slice")
            chosen.update(range(n)[slice(*parts)])
        elif "-" in item.lstrip("-"):
            a, b = item.lstrip("-").split("-", 1)
            lo = check(-num(a, item) if item.startswith("-") else num(a, item))
            chosen.update(range(lo, check(num(b, item)) + 1))
        else:
            chosen.add(check(num(item, item)))
    if not chosen:
        raise bad("no layer selected")
    kept = tuple(replace(layers[i], index=k, meta={**layers[i].meta, "source_index": i})
                 for k, i in enumerate(sorted(chosen)))
    return replace(layers, layers=kept, meta={**layers.meta, "selected_layers": sorted(chosen)})
