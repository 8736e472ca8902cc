"""Comparing runs: result rows without their wall-clock fields, and per-episode scores."""

from __future__ import annotations

from typing import Any

from skyvln_eval.metrics import EpisodeResult, MetricConventions, score_results
from skyvln_eval.metrics.results_io import result_to_json_dict

TIMING_FIELDS = (
    "latency_s",
    "queue_s",
    "wall_s",
    "llm_s",
    "solve_time_mean_ms",
    "solve_time_p50_ms",
    "solve_time_p95_ms",
    "solve_time_max_ms",
)


def comparable(result: EpisodeResult) -> dict[str, Any]:
    """A result without the fields that measure wall-clock time (latency, solve times)."""

    def strip(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in TIMING_FIELDS}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(result_to_json_dict(result))


def scores_of(results: list[EpisodeResult]) -> dict[str, tuple[float, float, float]]:
    scores = score_results(results, MetricConventions())
    return {
        row.episode_id: (row.success, row.spl, row.ne_m) for row in scores.itertuples(index=False)
    }


def same_runs(resumed: list[EpisodeResult], reference: list[EpisodeResult]) -> None:
    """Assert: one row per episode, the same episodes, rows and scores as the reference."""
    assert len({r.key for r in resumed}) == len(resumed), "an episode has two rows"
    by_key = {r.key: r for r in reference}
    assert sorted(r.key for r in resumed) == sorted(by_key), "rows lost or extra"
    for row in resumed:
        assert comparable(row) == comparable(by_key[row.key]), row.key
    assert scores_of(resumed) == scores_of(reference)
