"""Floats' JSON text in bulk: the writer's encoding of each float, on every magnitude."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyvln_eval.converters import float_text
from skyvln_eval.converters.float_text import float_texts, point_list_texts
from skyvln_eval.converters.writer import encode_json


def _every_magnitude(n: int, seed: int) -> np.ndarray:
    """Random bit patterns (every exponent, subnormals included) and rounded decimals."""
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 2**63, size=n, dtype=np.uint64) * np.uint64(2)
    bits += rng.integers(0, 2, size=n, dtype=np.uint64)
    patterns = bits.view(np.float64)
    decimals = np.array(
        [
            round(v, int(d))
            for v, d in zip(
                (rng.standard_normal(n) * 10.0 ** rng.integers(-12, 20, n)).tolist(),
                rng.integers(0, 12, n),
                strict=True,
            )
        ]
    )
    edges = [0.0, -0.0, 1e-4, -1e-4, 9.99e-5, 5e-324, 1e16, 9999999999999998.0, 1e22]
    values = np.concatenate([patterns, decimals, edges])
    return values[np.isfinite(values)]


def test_the_installed_orjson_passes_the_probe() -> None:
    # Not needed for the text (the repr path is the same), but without it runs are slower.
    assert float_text._FAST


@pytest.mark.parametrize("fast", [True, False])
def test_each_float_is_written_as_its_repr(fast: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(float_text, "_FAST", fast)
    values = _every_magnitude(50_000, seed=3)
    assert float_texts(values) == [repr(v) for v in values.tolist()]


@pytest.mark.parametrize("fast", [True, False])
def test_point_lists_are_the_writers_json(fast: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(float_text, "_FAST", fast)
    values = _every_magnitude(3 * 7 * 400, seed=5)[: 3 * 7 * 400]
    points = values.reshape(400, 7, 3)
    points[::5] = np.abs(points[::5]) + 1.0  # rows with no tiny value too
    points[1] = 2.0
    points[1, 0] = (3.2e-5, -7.5e-5, 1.25e-3)  # where orjson's notation is not repr's
    expected = [encode_json(row).decode() for row in points.tolist()]
    assert point_list_texts(points) == expected
    one = points[:1, :1]
    assert point_list_texts(one) == [encode_json(one[0].tolist()).decode()]


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=40))
def test_any_finite_floats(values: list[float]) -> None:
    assert float_texts(np.array(values)) == [repr(v) for v in values]


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="finite"):
        float_texts(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="1-D"):
        float_texts(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="finite"):
        point_list_texts(np.array([[[1.0, np.inf, 2.0]]]))
    with pytest.raises(ValueError, match="shape"):
        point_list_texts(np.zeros((2, 0, 3)))
    assert float_texts(np.array([])) == []
    assert point_list_texts(np.zeros((0, 4, 3))) == []
