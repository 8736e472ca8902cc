"""Many floats' JSON text at once, exactly as the writer's encoder writes each one.

The writer's JSON encoder writes a float as ``float.__repr__``. A dynamics run log writes
tens of thousands of floats per episode (each control step's state, reference, command
and the NMPC's predicted path), and ``repr`` one float at a time was most of the time of
its control messages. orjson formats a whole float64 array in C with the same shortest
round-trip digits and the same notation, except for magnitudes below 1e-4, where it writes
``0.0000123`` and Python writes ``1.23e-05``. Those few values are written by ``repr``.

A probe at import checks that rule on the installed orjson (values on both sides of each
notation change). If the probe disagrees anywhere, this module uses ``repr`` for every
value: slower, but the same text.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import orjson
from numpy.typing import NDArray

#: Below this magnitude (and above 0) orjson's notation differs from ``repr``'s.
_REPR_BELOW = 1e-4
_OPTIONS = orjson.OPT_SERIALIZE_NUMPY


def _needs_repr(values: NDArray[np.float64]) -> NDArray[np.bool_]:
    magnitude = np.abs(values)
    return (magnitude < _REPR_BELOW) & (magnitude > 0.0)


def _orjson_texts(values: NDArray[np.float64]) -> list[str]:
    """orjson's text of each value of a non-empty 1-D array."""
    return orjson.dumps(np.ascontiguousarray(values), option=_OPTIONS).decode()[1:-1].split(",")


def _probe() -> bool:
    """Whether the installed orjson writes like ``repr`` outside the small magnitudes."""
    probes = [0.0, -0.0, 1e-4, 1.0000000000000002e-4, 0.1, 1 / 3, 1.0, 2.5, 77.00000000019173]
    probes += [1e15, 9999999999999998.0, 1e16, 1.2345678901234567e16, 1e22, 1.7976931348623157e308]
    probes += [-p for p in probes]
    values = np.array(probes, dtype=np.float64)
    return _orjson_texts(values) == [repr(p) for p in probes]


_FAST = _probe()


def float_texts(values: NDArray[np.float64]) -> list[str]:
    """``float.__repr__`` of each value of a 1-D array of finite floats, in order."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"float_texts takes a 1-D array, got shape {values.shape}")
    if not np.isfinite(values).all():
        raise ValueError("float_texts takes finite values only (JSON has no NaN or infinity)")
    if not _FAST or len(values) == 0:
        return [repr(v) for v in values.tolist()]
    texts = _orjson_texts(values)
    for i in np.flatnonzero(_needs_repr(values)).tolist():
        texts[i] = repr(float(values[i]))
    return texts


def point_list_texts(points: NDArray[np.float64]) -> list[str]:
    """For an array of shape (rows, n, 3) of finite floats with n >= 1, each row's JSON
    text ``[[x,y,z],...]`` as the writer encodes the row's ``tolist()``."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[1] < 1 or points.shape[2] != 3:
        raise ValueError(f"point_list_texts takes shape (rows, n >= 1, 3), got {points.shape}")
    rows, n = points.shape[0], points.shape[1]
    if rows == 0:
        return []
    if not np.isfinite(points).all():
        raise ValueError("point_list_texts takes finite values only")
    template = "[" + ",".join(["[{},{},{}]"] * n) + "]"
    redo: Iterable[int] = range(rows)  # rows written value by value, through float_texts
    texts = [""] * rows
    if _FAST:
        # The rows' texts are separated by "]],[[" (no number contains a bracket); rows
        # with a value where orjson's notation is not repr's are written again.
        text = orjson.dumps(np.ascontiguousarray(points), option=_OPTIONS).decode()
        texts = ["[[" + row + "]]" for row in text[3:-3].split("]],[[")]
        redo = np.flatnonzero(_needs_repr(points).reshape(rows, -1).any(axis=1)).tolist()
    for r in redo:
        texts[r] = template.format(*float_texts(points[r].ravel()))
    return texts
