"""Per-episode result records: what a run leaves behind, and all metrics are computed from.

One :class:`EpisodeResult` per (run, episode). It holds the visited views (start
included) and the ground truth, so every metric can be recomputed later; optional
:class:`ControlSummary` (runs with dynamics) and :class:`LlmCall` records (LLM agents)
feed the safety and cost metrics. Nothing here is an average: aggregation and bootstrap
come later (:mod:`skyvln_eval.metrics.aggregate`, :mod:`skyvln_eval.metrics.stats`).

Views are ``[lat, lng]`` degrees, corner order front-left, front-right, back-right,
back-left, as in AVDN. Construction validates shapes and finiteness and raises
:class:`~skyvln_eval.errors.ResultRecordError` naming the episode and the field.
The file formats are in :mod:`skyvln_eval.metrics.results_io`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.constants import EPISODE_MODES, SPLITS, EpisodeMode
from skyvln_eval.avdn.json_values import shown
from skyvln_eval.errors import ResultRecordError, ValidationIssue
from skyvln_eval.llm_records import LlmCall, ModuleFailure, fallback_steps, module_usage

ResultStatus = Literal["ok", "degraded", "error"]
#: ``ok``: the agent flew the episode with every answer it asked for; ``degraded``: it
#: flew it, but some decision used a fallback action, some module's answer could not be
#: used, or (flown) some control step's solve failed and the controller fell back;
#: ``error``: the episode raised (harness, agent or controller), no LLM call of it
#: gave a usable answer, every decision's action was the fallback (the model chose none
#: of its moves), or a call got no answer from the endpoint (an outage after the retries,
#: no such route or model: the episode measures the endpoint, not the model). The rates
#: of each are reported; an ``error`` episode never counts as a success (its distances
#: still describe whatever it flew).
RESULT_STATUSES: tuple[ResultStatus, ...] = get_args(ResultStatus)
#: What names one episode's row in scores and cost tables: :attr:`EpisodeResult.key`.
KEY_COLUMNS: tuple[str, str, str, str] = ("system", "split", "mode", "episode_id")


def judge_status(
    calls: Sequence[LlmCall],
    failures: Sequence[ModuleFailure],
    agent_error: str | None,
    solve_failures: int = 0,
    decisions: int = 0,
) -> tuple[ResultStatus, str | None]:
    """An episode's status and, for ``error``, why (the first error text: of a request that
    failed or gave an unusable answer, ahead of a form the server refused, see
    :func:`_first_error`). ``solve_failures``: the flight's control steps whose solve
    failed (the controller fell back: hover, a shifted plan), whose flying is then not the
    controller's. ``decisions``: how many the agent made; when the action of every one
    was the fallback, the model chose none of the episode's moves and the flight is the
    fallback's, not a result of the model."""
    if agent_error is not None:
        return "error", agent_error
    if calls and not any(c.outcome == "ok" for c in calls):
        first = _first_error(calls)
        return "error", f"no LLM call of the episode gave a usable answer; first error: {first}"
    unanswered = next((c for c in calls if c.unanswered_after_retries), None)
    if unanswered is not None:
        # The endpoint never answered (an outage, a timeout after every retry): what the
        # agent then did measures the endpoint, not the model. An answer the model gave
        # but that could not be used, or a request the server refused for its content (a
        # prompt beyond the model's context), is the model's: it degrades the episode, or,
        # when no decision's action was the model's, makes it an error (below).
        return "error", (
            f"an LLM call got no answer (module {unanswered.module}, "
            f"{unanswered.attempt} attempt(s)); {unanswered.error}"
        )
    # After the endpoint's failure, which says why: the model's own failure to act.
    if decisions and len(fallback_steps(failures)) >= decisions:
        fell = next(f for f in failures if f.action_fallback)
        return "error", (
            f"no action of the episode was the model's: all {decisions} decision(s) fell back "
            f"to the {fell.substitute} ({fell.module}: {fell.reason})"
        )
    if failures or solve_failures:
        return "degraded", None
    return "ok", None


def _first_error(calls: Sequence[LlmCall]) -> str:
    """The first error of an attempt that failed or gave an unusable answer, else the first
    of a refused one. A refusal (a structured-output level or a parameter the server does
    not take) is negotiation that went on in another form: the request that failed says
    what went wrong (a server that only streams refuses every level first, then gives its
    reason to the plain request)."""
    failed = next((c.error for c in calls if c.error and c.outcome != "refused"), None)
    return failed or next((c.error for c in calls if c.error), "no answer")


def _issue(message: str, field_name: str, episode_id: str | None) -> ResultRecordError:
    return ResultRecordError(
        ValidationIssue(
            file="<EpisodeResult>", message=message, episode_id=episode_id, field=field_name
        )
    )


def _check_numbers(value: list[Any], field_name: str, episode_id: str | None) -> None:
    """Every leaf of the nested lists ``value`` is a JSON number (not a boolean, a string)."""
    stack: list[tuple[Any, str]] = [(value, field_name)]
    while stack:
        item, where = stack.pop()
        if isinstance(item, list):
            stack.extend((x, f"{where}[{i}]") for i, x in reversed(list(enumerate(item))))
        elif isinstance(item, np.ndarray):  # of an official .npy: numbers unless it says not
            if item.dtype.kind not in "fiu":
                raise _issue(f"expected numbers, got an array of {item.dtype}", where, episode_id)
        elif isinstance(item, bool | np.bool_) or not isinstance(
            item, int | float | np.integer | np.floating
        ):
            raise _issue(f"expected a number, got {shown(item)}", where, episode_id)


def as_views(
    value: ArrayLike, field_name: str, episode_id: str | None, min_len: int
) -> NDArray[np.float64]:
    """A read-only ``(K, 4, 2)`` float64 copy of ``value``, checked finite, ``K >= min_len``."""
    if isinstance(value, list):  # e.g. read from JSON: numpy takes true for 1.0, "37.7" for 37.7
        _check_numbers(value, field_name, episode_id)
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        for k, view in enumerate(value if isinstance(value, list | tuple) else ()):
            if isinstance(view, np.ndarray):  # of an official .npy
                if view.shape != (4, 2):
                    raise _issue(
                        f"a view is 4 [lat, lng] corners, got an array of shape {view.shape}",
                        f"{field_name}[{k}]",
                        episode_id,
                    ) from None
            elif not isinstance(view, list | tuple) or len(view) != 4:  # a ragged view
                got = len(view) if isinstance(view, list | tuple) else type(view).__name__
                raise _issue(
                    f"a view is 4 [lat, lng] corners, got {got}", f"{field_name}[{k}]", episode_id
                ) from None
        raise _issue(f"not an array of numbers ({exc})", field_name, episode_id) from None
    if arr.size == 0 and min_len == 0:
        arr = arr.reshape(0, 4, 2)
    if arr.ndim != 3 or arr.shape[1:] != (4, 2):
        raise _issue(
            f"expected shape (K, 4, 2) [lat, lng] corners, got {arr.shape}", field_name, episode_id
        )
    if len(arr) < min_len:
        raise _issue(f"needs at least {min_len} view(s), got {len(arr)}", field_name, episode_id)
    bad = np.argwhere(~np.isfinite(arr))
    if len(bad):
        k, c, a = (int(v) for v in bad[0])
        raise _issue(
            f"non-finite value {arr[k, c, a]!r} (NaN or inf)",
            f"{field_name}[{k}][{c}][{a}]",
            episode_id,
        )
    for axis, (name, limit) in enumerate((("latitude", 90.0), ("longitude", 180.0))):
        outside = np.argwhere(np.abs(arr[..., axis]) > limit)
        if len(outside):
            k, c = (int(v) for v in outside[0])
            raise _issue(
                f"{name} {arr[k, c, axis]!r} is outside [-{limit:g}, {limit:g}] (corners are "
                "[lat, lng]: swapped?)",
                f"{field_name}[{k}][{c}][{axis}]",
                episode_id,
            )
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class ControlSummary:
    """Safety and control statistics of one closed-loop episode (see :mod:`.safety`).

    ``duration_s`` is from the first step's start to the last step's end (``None`` for a
    log of one step, whose length the log does not hold); ``min_clearance_m`` is ``None``
    when the episode had no obstacles; the RMSEs are of
    flown minus reference (roll and pitch against the commanded angles, yaw wrapped to
    (-pi, pi]); solve times are over every control step.
    """

    controller: str
    scenario: str
    steps: int
    duration_s: float | None
    collision_steps: int
    min_clearance_m: float | None
    constraint_violation_steps: int
    solve_failures: int
    rmse_x_m: float
    rmse_y_m: float
    rmse_z_m: float
    rmse_roll_rad: float
    rmse_pitch_rad: float
    rmse_yaw_rad: float
    solve_time_mean_ms: float
    solve_time_p50_ms: float
    solve_time_p95_ms: float
    solve_time_max_ms: float
    #: Steps solved only by relaxing the obstacle constraint (its soft slack used: the
    #: controller found no path that kept out, and took the least intrusion); None for a
    #: controller without an obstacle constraint (the PID) and in results written before
    #: it was recorded.
    soft_steps: int | None = None

    @property
    def collided(self) -> bool:
        return self.collision_steps > 0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("controller", "scenario"):
                continue
            if value is None and f.name in ("duration_s", "min_clearance_m", "soft_steps"):
                continue
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
            ):
                raise _issue(f"must be a finite number, got {value!r}", f"control.{f.name}", None)

    def to_json_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, eq=False)
class EpisodeResult:
    """What one run did on one episode: the input of every metric.

    - ``visited_views``: ``(K, 4, 2)``, the start view first, in visiting order; ``K = 0``
      only when the episode failed before its first view.
    - ``gt_path_corners``: ``(N, 4, 2)``, ``N >= 1``, the ground truth (start first).
      ``N = 1`` is the start view alone: the ground truth is withheld (the real AVDN
      test_unseen), and the episode cannot be scored (:attr:`has_ground_truth`).
    - ``system``: the run / configuration label shown in tables (e.g. ``"SkyVLN full"``,
      ``"rule-based backend"``); rows are labelled by it.
    - ``control_log``: where the episode's control log (parquet) lives, relative to the
      results file, so the safety metrics can be recomputed; ``control`` its summary.
    - ``decisions``: how many decisions the agent made; ``module_failures``: the modules
      whose answers could not be used, per decision (see :func:`judge_status`).
    - ``extra``: JSON-able extra facts (seeds, config hashes, wall time, ``oracle``: whether
      the harness's oracle flew it, absent in rows of older runs; ``llm_use_recorded``:
      ``False`` when no one recorded the agent's LLM calls and questions, as for
      predictions made elsewhere: their counts, cost and time are unknown, not 0), kept
      verbatim.
    """

    episode_id: str
    split: str
    mode: EpisodeMode
    system: str
    status: ResultStatus
    visited_views: NDArray[np.float64]
    gt_path_corners: NDArray[np.float64]
    error: str | None = None
    control: ControlSummary | None = None
    control_log: str | None = None
    llm_calls: tuple[LlmCall, ...] = ()
    decisions: int = 0
    module_failures: tuple[ModuleFailure, ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        # Short, for notebooks: the default repr printed every view, call and fact (21 KB
        # for one sample episode); the fields are all there to read.
        first = (self.error or "").strip().splitlines()[:1]
        error = f", error={first[0][:80]!r}" if first else ""
        return (
            f"EpisodeResult({self.split}/{self.episode_id}, {self.mode}, {self.system!r}, "
            f"{self.status}{error}, {len(self.visited_views)} views, "
            f"{self.decisions} decisions, {len(self.llm_calls)} LLM calls)"
        )

    @property
    def stopped_the_run(self) -> bool:
        """Whether the row only records the run stopping there (``extra["fatal"]``: refused
        credentials, a full disk): no result of its episode, which runs again."""
        return "fatal" in self.extra

    @property
    def has_ground_truth(self) -> bool:
        """Whether there is a route to score against (more than the start view)."""
        return len(self.gt_path_corners) >= 2

    @property
    def segments_cut_short(self) -> int | None:
        """How many of a flown episode's segments ended at ``max_segment_time_s`` without
        the drone settling at their target (a crash's last segment is the crash, not
        counted); ``None`` when the row does not say (not flown, or an older run)."""
        reached = self.extra.get("segments_reached")
        if self.control is None or not isinstance(reached, list):
            return None
        if self.control.collided and reached and not reached[-1]:
            reached = reached[:-1]
        return sum(not r for r in reached)

    @property
    def llm_use_recorded(self) -> bool:
        """Whether ``llm_calls`` (and the questions asked) are the agent's record: an empty
        one then means no call, at no cost; otherwise nothing is known of them."""
        return self.extra.get("llm_use_recorded", True) is not False

    @property
    def fallback_decisions(self) -> int:
        """Decisions whose action was the safe fallback (the action module failed)."""
        return len(fallback_steps(self.module_failures))

    def llm_modules(self) -> dict[str, dict[str, Any]]:
        """Per agent module: calls, failed calls, parse failures, repairs, fallbacks, tokens
        and LLM seconds (:func:`~skyvln_eval.llm_records.module_usage`)."""
        return module_usage(self.llm_calls, self.module_failures)

    def __post_init__(self) -> None:
        eid = self.episode_id if isinstance(self.episode_id, str) else None
        for name in ("episode_id", "split", "system"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise _issue(f"must be a non-empty string, got {value!r}", name, eid)
        if self.split not in SPLITS:  # a table would leave an unknown split out unsaid
            raise _issue(f"must be one of {SPLITS}, got {self.split!r}", "split", eid)
        if self.mode not in EPISODE_MODES:
            raise _issue(f"must be one of {EPISODE_MODES}, got {self.mode!r}", "mode", eid)
        if self.status not in RESULT_STATUSES:
            raise _issue(f"must be one of {RESULT_STATUSES}, got {self.status!r}", "status", eid)
        object.__setattr__(
            self, "visited_views", as_views(self.visited_views, "visited_views", eid, 0)
        )
        object.__setattr__(
            self, "gt_path_corners", as_views(self.gt_path_corners, "gt_path_corners", eid, 1)
        )
        if len(self.visited_views) == 0 and self.status != "error":
            raise _issue(
                f"a {self.status!r} episode must include at least its start view",
                "visited_views",
                eid,
            )
        if self.status == "error" and not self.error:
            raise _issue("an 'error' episode must say what went wrong", "error", eid)
        if isinstance(self.decisions, bool) or not isinstance(self.decisions, int):
            raise _issue(f"must be an integer, got {self.decisions!r}", "decisions", eid)
        if self.decisions < 0:
            raise _issue(f"must be >= 0, got {self.decisions}", "decisions", eid)
        object.__setattr__(self, "llm_calls", tuple(self.llm_calls))
        object.__setattr__(self, "module_failures", tuple(self.module_failures))
        for call in self.llm_calls:
            if not isinstance(call, LlmCall):
                raise _issue(
                    f"expected LlmCall records, got {type(call).__name__}", "llm_calls", eid
                )
        for failure in self.module_failures:
            if not isinstance(failure, ModuleFailure):
                raise _issue(
                    f"expected ModuleFailure records, got {type(failure).__name__}",
                    "module_failures",
                    eid,
                )

    @property
    def key(self) -> tuple[str, str, str, str]:
        """``(system, split, mode, episode_id)``: unique within a set of results."""
        return (self.system, self.split, self.mode, self.episode_id)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EpisodeResult):
            return NotImplemented
        return (
            self.key == other.key
            and self.status == other.status
            and self.visited_views.shape == other.visited_views.shape
            and bool(np.array_equal(self.visited_views, other.visited_views))
            and self.gt_path_corners.shape == other.gt_path_corners.shape
            and bool(np.array_equal(self.gt_path_corners, other.gt_path_corners))
            and self.error == other.error
            and self.control == other.control
            and self.control_log == other.control_log
            and self.llm_calls == other.llm_calls
            and self.decisions == other.decisions
            and self.module_failures == other.module_failures
            and dict(self.extra) == dict(other.extra)
        )

    __hash__ = None  # type: ignore[assignment]
