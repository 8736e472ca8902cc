"""Metrics: pure functions over per-episode records, aggregation, intervals and paired tests.

Follow a run: its :class:`EpisodeResult` rows (visited views, ground truth, status,
optional control summary and LLM calls; files in :mod:`.results_io`) go through
:func:`score_results` under a :class:`MetricConventions`, giving one row of official
AVDN, R2R-family, cost and control metrics per episode; :func:`summarise` averages them
per system and split (with Wilson or seeded bootstrap intervals, over episodes or whole
trajectories), :func:`check_complete`
refuses runs that miss episodes, :func:`compare_systems` tests two systems on the same episodes.
Predictions made elsewhere (the official ``.npy`` output, a JSON format) are read by
:func:`read_predictions` and joined with ground truth by :func:`results_from_predictions`.
Control logs give safety metrics through :func:`control_metrics`. Scores files
(``skyvln-eval score``'s ``scores.csv``) are read back by :func:`read_scores`, with the
conventions they were made under.
"""

from skyvln_eval.avdn.records import trajectory_of
from skyvln_eval.metrics.aggregate import (
    BINARY_METRICS,
    CI_METHODS,
    CI_UNITS,
    DISPLAY_NAMES,
    LOWER_IS_BETTER,
    PERCENT_METRICS,
    ErroredEpisodesWarning,
    check_complete,
    check_scores_complete,
    compare_systems,
    summarise,
    unit_of,
)
from skyvln_eval.metrics.conventions import METRICS_VERSION, MetricConventions
from skyvln_eval.metrics.cost import COST_COLUMNS, episode_costs, module_costs, summarise_costs
from skyvln_eval.metrics.official import OFFICIAL_COLUMNS, official_metrics, view_success
from skyvln_eval.metrics.predictions import (
    Prediction,
    ground_truth_episodes,
    read_official_npy,
    read_predictions,
    read_predictions_json,
    results_from_predictions,
    write_predictions_json,
)
from skyvln_eval.metrics.r2r import R2R_COLUMNS, dtw_and_coverage, dtw_distance, r2r_metrics
from skyvln_eval.metrics.records import (
    RESULT_STATUSES,
    ControlSummary,
    EpisodeResult,
    LlmCall,
    ResultStatus,
)
from skyvln_eval.metrics.results_io import (
    RESULTS_VERSION,
    read_results,
    result_from_json_dict,
    result_to_json_dict,
    write_results,
)
from skyvln_eval.metrics.safety import (
    CONTROL_LOG_COLUMNS,
    check_control_log,
    control_metrics,
    read_control_log,
    summarise_control,
    tracking_errors,
)
from skyvln_eval.metrics.scores_io import read_many_scores, read_scores, write_scores
from skyvln_eval.metrics.scoring import METRIC_UNITS, score_results
from skyvln_eval.metrics.stats import (
    ConfidenceInterval,
    PairedComparison,
    bootstrap_ci,
    bootstrap_means,
    paired_comparison,
    wilson_interval,
)
from skyvln_eval.metrics.view_overlap import sparse_hull_iou

__all__ = [
    "BINARY_METRICS",
    "CI_METHODS",
    "CI_UNITS",
    "CONTROL_LOG_COLUMNS",
    "COST_COLUMNS",
    "DISPLAY_NAMES",
    "LOWER_IS_BETTER",
    "METRICS_VERSION",
    "METRIC_UNITS",
    "OFFICIAL_COLUMNS",
    "PERCENT_METRICS",
    "R2R_COLUMNS",
    "RESULTS_VERSION",
    "RESULT_STATUSES",
    "ConfidenceInterval",
    "ControlSummary",
    "EpisodeResult",
    "ErroredEpisodesWarning",
    "LlmCall",
    "MetricConventions",
    "PairedComparison",
    "Prediction",
    "ResultStatus",
    "bootstrap_ci",
    "bootstrap_means",
    "check_complete",
    "check_control_log",
    "check_scores_complete",
    "compare_systems",
    "control_metrics",
    "dtw_and_coverage",
    "dtw_distance",
    "episode_costs",
    "ground_truth_episodes",
    "module_costs",
    "official_metrics",
    "paired_comparison",
    "r2r_metrics",
    "read_control_log",
    "read_many_scores",
    "read_official_npy",
    "read_predictions",
    "read_predictions_json",
    "read_results",
    "read_scores",
    "result_from_json_dict",
    "result_to_json_dict",
    "results_from_predictions",
    "score_results",
    "sparse_hull_iou",
    "summarise",
    "summarise_control",
    "summarise_costs",
    "tracking_errors",
    "trajectory_of",
    "unit_of",
    "view_success",
    "wilson_interval",
    "write_predictions_json",
    "write_results",
    "write_scores",
]
