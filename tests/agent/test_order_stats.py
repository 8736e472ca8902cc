"""The order statistics perception uses are numpy's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from skyvln_eval.agent.order_stats import column_median_and_percentiles, column_medians

SIZES = [*range(1, 13), 19, 20, 21, 199, 200, 399, 1000]


def _blocks(seed: int):
    rng = np.random.default_rng(seed)
    for size in SIZES:
        for kind in ("spread", "ties", "signed zeros", "tiny and huge"):
            block = rng.normal(500.0, 300.0, (size, 2))
            if kind == "ties":
                block = np.round(block / 100.0) * 100.0
            elif kind == "signed zeros":
                block = rng.choice([-0.0, 0.0, 1.0, -1.0], (size, 2))
            elif kind == "tiny and huge":
                block = rng.choice([5e-324, -1e300, 1e-3, 3.0, 1e300], (size, 2))
            yield size, kind, block


def test_column_medians_are_np_median() -> None:
    for size, kind, block in _blocks(3):
        got = np.array(column_medians(block))
        assert got.tobytes() == np.median(block, axis=0).tobytes(), (size, kind)
    assert np.isnan(column_medians(np.zeros((0, 2)))).all()


@pytest.mark.parametrize("percents", [(5, 95), (0, 50, 100), (12.5, 33.3, 66.7, 99.9)])
def test_medians_and_percentiles_are_numpy_s(percents: tuple[float, ...]) -> None:
    for size, kind, block in _blocks(5):
        median, values = column_median_and_percentiles(block.copy(), percents)
        assert median.tobytes() == np.median(block, axis=0).tobytes(), (size, kind)
        expected = np.percentile(block, list(percents), axis=0)
        assert values.tobytes() == expected.tobytes(), (size, kind, percents)


def test_an_empty_block_is_refused() -> None:
    with pytest.raises(ValueError, match="empty block"):
        column_median_and_percentiles(np.zeros((0, 2)), (5, 95))


def test_blocks_with_nan_get_numpy_s_answers() -> None:
    block = np.array([[1.0, np.nan], [2.0, 3.0], [4.0, 5.0]])
    assert np.array(column_medians(block)).tobytes() == np.median(block, axis=0).tobytes()
    median, values = column_median_and_percentiles(block, (5, 95))
    assert median.tobytes() == np.median(block, axis=0).tobytes()
    assert values.tobytes() == np.percentile(block, [5, 95], axis=0).tobytes()
