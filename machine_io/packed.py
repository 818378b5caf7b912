"""Sequences stored packed: the command texts of a program in one buffer, numbers in arrays.

A program of millions of commands keeps a few bytes per command
(:class:`PackedTexts`, :class:`PackedNumbers`) instead of a Python object each.
"""

from __future__ import annotations

import itertools
from array import array
from collections.abc import Iterator, Sequence
from typing import Any, overload

__all__ = ["PackedNumbers", "PackedTexts"]


class _Packed:
    """Shared behaviour of the packed sequences: equality with any sequence, short repr."""

    def __len__(self) -> int:  # pragma: no cover - overridden
        raise NotImplementedError

    def __iter__(self) -> Iterator[Any]:  # pragma: no cover - overridden
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (_Packed, tuple, list)):
            return len(self) == len(other) and all(
                a == b for a, b in zip(self, other, strict=True))
        return NotImplemented

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        head = ", ".join(repr(v) for v in itertools.islice(self, 3))
        more = ", …" if len(self) > 3 else ""
        return f"{type(self).__name__}([{head}{more}], {len(self)} items)"


class PackedTexts(_Packed, Sequence[str]):
    """Command texts stored as one UTF-8 buffer and end offsets.

    A tuple of millions of ``str`` costs about 70 bytes per command on top of
    the text; this costs 8. Items are decoded when asked for; slices give tuples.

    Parameters
    ----------
    blob
        The texts, one after the other.
    ends
        End offset of each text in ``blob`` (the start is the previous end).
    """

    __slots__ = ("_blob", "_ends")

    def __init__(self, blob: bytes | bytearray, ends: array) -> None:
        self._blob = blob  # kept as given: a copy of a bytearray would double it for a moment
        self._ends = ends

    def __len__(self) -> int:
        return len(self._ends)

    def _span(self, i: int) -> tuple[int, int]:
        return (self._ends[i - 1] if i else 0), self._ends[i]

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[str, ...]: ...

    def __getitem__(self, index: int | slice) -> str | tuple[str, ...]:
        if isinstance(index, slice):
            return tuple(self[i] for i in range(*index.indices(len(self))))
        n = len(self._ends)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError("command index out of range")
        a, b = self._span(index)
        return self._blob[a:b].decode("utf-8")

    def __iter__(self) -> Iterator[str]:
        blob = self._blob
        a = 0
        for b in self._ends:
            yield blob[a:b].decode("utf-8")
            a = b

    def sizes(self) -> Iterator[int]:
        """Length of each text in bytes (UTF-8), without decoding."""
        a = 0
        for b in self._ends:
            yield b - a
            a = b


class PackedNumbers(_Packed, Sequence[Any]):
    """Numbers in an :class:`array.array` (8 bytes each, not a Python object each).

    Parameters
    ----------
    values
        The numbers (``array("q")`` for line numbers, ``array("d")`` for seconds).
    """

    __slots__ = ("_values",)

    def __init__(self, values: array) -> None:
        self._values = values

    def __len__(self) -> int:
        return len(self._values)

    @overload
    def __getitem__(self, index: int) -> Any: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[Any, ...]: ...

    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return tuple(self._values[index])
        return self._values[index]

    def __iter__(self) -> Iterator[Any]:
        return iter(self._values)
