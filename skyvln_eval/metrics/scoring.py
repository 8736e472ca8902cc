"""Score episode results: one row of every per-episode metric per result.

:func:`score_results` is the one entry point: official AVDN metrics, the R2R family
(under the given :class:`MetricConventions`), LLM cost totals and control statistics,
as a pandas DataFrame keyed by ``system, split, mode, episode_id``, with each episode's
``status`` and ``oracle`` (whether the harness's oracle flew it: a reference a table never
ranks; empty where the results do not say, as those of older runs and predictions).
Nothing is averaged here (see :mod:`.aggregate`). Identical inputs give identical frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.errors import MetricInputError, NoGroundTruthError
from skyvln_eval.metrics.batch import pack_views
from skyvln_eval.metrics.conventions import CONVENTIONS_ATTR, MetricConventions
from skyvln_eval.metrics.cost import COST_COLUMNS, episode_totals
from skyvln_eval.metrics.official import OFFICIAL_COLUMNS, official_metrics
from skyvln_eval.metrics.r2r import R2R_COLUMNS, r2r_metrics
from skyvln_eval.metrics.records import RESULT_STATUSES, EpisodeResult
from skyvln_eval.metrics.results_io import check_one_configuration_per_system, check_unique

#: Text columns of the scores frame, after ``oracle``, each empty where not said:
#: what answered the LLM calls, how the episode ran, and the first line of its error.
TEXT_COLUMNS = ("llm_backend", "detector", "execution_mode", "error")

#: Control columns of the scores frame (NaN-free: missing summaries leave them empty,
#: ``has_control`` says which rows have them; ``min_clearance_m`` is empty without
#: obstacles).
CONTROL_COLUMNS: dict[str, str] = {
    "collision_steps": "steps",
    "collided": "0/1",
    "min_clearance_m": "m",
    "constraint_violation_steps": "steps",
    "solve_failures": "steps",
    "soft_steps": "steps",
    "segments_cut_short": "segments",
    "rmse_x_m": "m",
    "rmse_y_m": "m",
    "rmse_z_m": "m",
    "rmse_yaw_rad": "rad",
    "solve_time_mean_ms": "ms",
    "solve_time_p95_ms": "ms",
}

#: Share of episodes of each status (0/1 per episode; percent when summarised), and the
#: episode's wall time.
STATUS_COLUMNS: dict[str, str] = {
    **{f"status_{status}": "0/1" for status in RESULT_STATUSES},
    "wall_s": "s",
    "questions_asked": "questions",
    "questions_answered": "questions",
}

#: Every metric column of the scores frame with its unit.
METRIC_UNITS: dict[str, str] = {
    **OFFICIAL_COLUMNS,
    **R2R_COLUMNS,
    **COST_COLUMNS,
    **CONTROL_COLUMNS,
    **STATUS_COLUMNS,
}


def can_succeed(
    statuses: ArrayLike, flew: ArrayLike, crashed: ArrayLike | None = None
) -> NDArray[np.bool_]:
    """Which episodes a success can be counted for: an 'error' episode never succeeds,
    whatever it flew (its distances still describe its path); nor does one whose flight
    ``crashed`` into an obstacle (see :func:`crashed_flights`); a 'degraded' one is scored
    on its views like an 'ok' one; an episode with no view flew nothing."""
    ok = (np.asarray(statuses) != "error") & np.asarray(flew, dtype=bool)
    if crashed is not None:
        ok &= ~np.asarray(crashed, dtype=bool)
    return ok


def touched_an_obstacle(result: EpisodeResult) -> bool:
    """Whether the episode's flight touched an obstacle (dynamics mode)."""
    return result.control is not None and result.control.collided


def touched_obstacles(scores: pd.DataFrame) -> NDArray[np.bool_]:
    """:func:`touched_an_obstacle` for each row of a scores frame (its ``collided``
    column; none without it: runs without control)."""
    if "collided" not in scores.columns:
        return np.zeros(len(scores), dtype=bool)
    return scores["collided"].astype("Float64").fillna(0.0).to_numpy(np.float64) > 0.0


def crashed_flights(scores: pd.DataFrame, conventions: MetricConventions) -> NDArray[np.bool_]:
    """Which rows of a scores frame flew into an obstacle and so cannot succeed under
    ``conventions`` (``collision_fails``; none with the convention off)."""
    if not conventions.collision_fails:
        return np.zeros(len(scores), dtype=bool)
    return touched_obstacles(scores)


def _check_are_results(results: object) -> None:
    """Refuse what is not a sequence of episode results, saying what it is instead."""
    takes = "score_results takes episode results (run_results(run_dir), read_results(path))"
    if isinstance(results, pd.DataFrame):
        raise MetricInputError(f"{takes}, not a DataFrame: these are scores already")
    if isinstance(results, str | bytes) or not isinstance(results, Sequence):
        raise MetricInputError(f"{takes}, not {type(results).__name__}")
    other = next((r for r in results if not isinstance(r, EpisodeResult)), None)
    if other is not None:
        raise MetricInputError(f"{takes}; this sequence holds a {type(other).__name__}")


def score_results(
    results: Sequence[EpisodeResult], conventions: MetricConventions | None = None
) -> pd.DataFrame:
    """Every per-episode metric of ``results``, one row each, in input order.

    Raises :class:`MetricInputError` on empty input,
    :class:`~skyvln_eval.errors.ResultRecordError` on duplicate episodes or on one
    system's rows made by different run configurations (a table would pool them), and
    :class:`~skyvln_eval.errors.NoGroundTruthError` on episodes whose ground truth is
    withheld (scored, they would be failures with a negative progress).
    """
    conventions = conventions or MetricConventions()
    _check_are_results(results)
    if not results:
        raise MetricInputError("no episode results to score")
    check_unique(results)
    check_one_configuration_per_system(results)
    withheld = [r for r in results if not r.has_ground_truth]
    if withheld:
        split = withheld[0].split
        raise NoGroundTruthError(split, [r.episode_id for r in withheld if r.split == split])
    gt = pack_views([r.gt_path_corners for r in results])
    visited = pack_views(
        [r.visited_views for r in results], stand_ins=[r.gt_path_corners[0] for r in results]
    )
    crashed = [conventions.collision_fails and touched_an_obstacle(r) for r in results]
    ok = can_succeed(np.array([r.status for r in results]), ~visited.empty, crashed)
    frame = pd.DataFrame(
        {
            "system": [r.system for r in results],
            "split": [r.split for r in results],
            "mode": [r.mode for r in results],
            "episode_id": [r.episode_id for r in results],
            "status": [r.status for r in results],
            "oracle": pd.array([_oracle(r) for r in results], dtype="boolean"),
            "llm_backend": pd.array([_said(r, "llm_backend") for r in results], dtype="string"),
            "detector": pd.array([_said(r, "detector") for r in results], dtype="string"),
            "execution_mode": pd.array([_execution_mode(r) for r in results], dtype="string"),
            "error": pd.array([_first_line(r.error) for r in results], dtype="string"),
            "n_views": visited.lengths,
            "n_gt_views": gt.lengths,
        }
    )
    metrics = official_metrics(visited, gt, ok, legacy_gp=conventions.legacy_gp)
    errored = np.array([r.status == "error" for r in results], dtype=bool)
    metrics.update(r2r_metrics(visited, gt, ok, conventions, errored))
    for name, values in metrics.items():
        frame[name] = values
    for status in RESULT_STATUSES:  # rates of each status, reported like any metric
        frame[f"status_{status}"] = [float(r.status == status) for r in results]
    # Episode wall time where the run recorded it, else NaN: float64 as the cost columns,
    # and as read_scores reads it back (it was Float64 here, float64 there).
    frame["wall_s"] = [_wall_s(r) for r in results]
    questions = [r.extra.get("questions") or [] for r in results]  # asked of the commander
    recorded = [r.llm_use_recorded for r in results]  # else how many is unknown
    frame["questions_asked"] = [
        float(len(q)) if known else math.nan for q, known in zip(questions, recorded, strict=True)
    ]
    frame["questions_answered"] = [
        float(sum(x.get("answer") is not None for x in q)) if known else math.nan
        for q, known in zip(questions, recorded, strict=True)
    ]
    frame = pd.concat([frame, episode_totals(results)], axis=1)
    frame["has_control"] = [r.control is not None for r in results]
    with_control = [k for k, r in enumerate(results) if r.control is not None]
    for column in CONTROL_COLUMNS:
        cells: list[float | None] = [None] * len(results)
        for k in with_control:  # only rows with dynamics; the rest stay empty
            control = results[k].control
            assert control is not None
            if column == "collided":
                cells[k] = float(control.collided)
            elif column == "segments_cut_short":  # of the rollout, not the control summary
                cut = results[k].segments_cut_short
                cells[k] = None if cut is None else float(cut)
            else:
                cells[k] = getattr(control, column)
        frame[column] = pd.array(cells, dtype="Float64")
    bad = [c for c in metrics if not np.isfinite(frame[c].to_numpy(np.float64)).all()]
    if bad:  # a bug, never user input (inputs are checked finite): fail loudly
        raise MetricInputError(f"non-finite per-episode values in {bad}")
    # The frame says which conventions scored it, so a table of it cannot say others.
    frame.attrs[CONVENTIONS_ATTR] = conventions
    return frame


def _wall_s(result: EpisodeResult) -> float:
    wall = result.extra.get("wall_s")  # a number >= 0 or absent: checked on reading
    return math.nan if wall is None else float(wall)


def _oracle(result: EpisodeResult) -> bool | None:
    """Whether the harness's oracle flew ``result`` (its ``extra["oracle"]``), ``None``
    when its run did not say (results of older runs, predictions)."""
    value = result.extra.get("oracle")
    if value is None or isinstance(value, bool):
        return value
    where = "/".join(result.key)
    raise MetricInputError(f"{where}: extra.oracle must be true or false, got {value!r}")


def _execution_mode(result: EpisodeResult) -> str | None:
    """How the episode ran: ``official`` (AVDN's step) or ``dynamics`` (flown), from its
    ``extra["execution_mode"]``; ``None`` where the results do not say. (The ``mode``
    column is the AVDN episode mode, ``andh`` or ``andh-full``.)"""
    value = result.extra.get("execution_mode")
    return value if isinstance(value, str) else None


def _first_line(error: str | None) -> str | None:
    """An episode's error, as its first line (the rest is in the results file)."""
    return None if not error else error.strip().splitlines()[0]


def _said(result: EpisodeResult, key: str) -> str | None:
    """What ``result``'s run said of it in ``extra[key]``: ``llm_backend``, the backend
    that answered its LLM calls, or ``detector``, the detector that found its landmarks;
    ``None`` for an agent without them or a run that did not say."""
    value = result.extra.get(key)
    if value is None or isinstance(value, str):
        return value
    where = "/".join(result.key)
    raise MetricInputError(f"{where}: extra.{key} must be a string, got {value!r}")
