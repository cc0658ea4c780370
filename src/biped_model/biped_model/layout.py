"""Array-backed records: a flat float64 array whose named fields are declared once.

Pure Python + NumPy, no ROS. A :class:`Layout` is declared from (name, size) pairs, in order; the offset
of each field is generated from the declaration (the running sum of the sizes before it) and exposed
as ``layout.at`` -- a ``NamedTuple`` of ints, which numba freezes into compiled code as constants
when it is a module global (``mem[M.p]`` compiles to a fixed offset). The Python objects keep their
state in such arrays (properties over the fields) and the compiled kernels take the same arrays, so
the two sides cannot disagree on where a field lives.

Numbers only: a boolean field holds 0.0 / 1.0, an integer field (a stance, a step index) its exact
float (integers up to 2^53 are exact in float64).
"""
from __future__ import annotations

from collections import namedtuple
from typing import Sequence

import numpy as np


class LayoutError(ValueError):
    """A layout declaration is inconsistent (message names the field)."""


class SnapshotUnsupported(RuntimeError):
    """An object's state cannot be captured by its ``snapshot()`` (the message says what it holds besides its
    layout arrays, e.g. a sensor model's random state): the caller runs from the start instead."""


class Layout:
    """Fields of a flat float64 array: ``fields`` is a sequence of ``(name, size)`` with size >= 1.

    ``at`` (NamedTuple): the offset of every field; ``size``: the array length; ``sizes``: each field's
    size; ``slice(name)``: the field's slice; ``new()``: a zero array of the layout."""

    def __init__(self, name: str, fields: Sequence[tuple[str, int]]):
        names, offsets, sizes, off = [], [], {}, 0
        for fname, size in fields:
            if not isinstance(fname, str) or not fname.isidentifier() or fname.startswith("_"):
                raise LayoutError(f"{name}: field name {fname!r} must be a public identifier")
            if fname in sizes:
                raise LayoutError(f"{name}: field {fname!r} declared twice")
            if isinstance(size, bool) or not isinstance(size, int) or size < 1:
                raise LayoutError(f"{name}: field {fname!r} has size {size!r}, must be an int >= 1")
            names.append(fname)
            offsets.append(off)
            sizes[fname] = size
            off += size
        if not names:
            raise LayoutError(f"{name}: no fields")
        self.name = name
        self.at = namedtuple(f"{name}_offsets", names)(*offsets)
        self.sizes = sizes
        self.size = off

    def slice(self, field: str) -> slice:
        o = getattr(self.at, field)
        return slice(o, o + self.sizes[field])

    def new(self) -> np.ndarray:
        return np.zeros(self.size)

    def __repr__(self) -> str:
        return f"Layout({self.name!r}, {[(n, self.sizes[n]) for n in self.at._fields]})"


def scalar(layout: Layout, field: str) -> property:
    """A float property over ``field`` (size 1) of the layout array ``self.<array>``, where the owner class
    names its array in ``_layout_array``."""
    if layout.sizes[field] != 1:
        raise LayoutError(f"{layout.name}.{field} has size {layout.sizes[field]}, not a scalar")
    o = getattr(layout.at, field)

    def get(self) -> float:
        return float(getattr(self, self._layout_array)[o])

    def set_(self, value: float) -> None:
        getattr(self, self._layout_array)[o] = value
    return property(get, set_, doc=f"{layout.name}.{field}")
