"""LLM use per episode and per agent module: calls, failures, fallbacks, tokens, cost, time.

Inputs are the :class:`~skyvln_eval.llm_records.LlmCall` and
:class:`~skyvln_eval.llm_records.ModuleFailure` records of each
:class:`~skyvln_eval.metrics.records.EpisodeResult`. Per-episode values are columns of the
scores frame (:data:`COST_COLUMNS`); :func:`module_costs` gives one row per (episode,
module) and :func:`summarise_costs` aggregates either over episodes.

Unknown stays unknown: an episode's cost is NaN when any of its attempts had no price or
no token count, its token counts when any answered attempt reported none, and every mean
over such an episode is NaN too, shown as "n/a" (:data:`UNKNOWN_IF_ANY_UNKNOWN`). A failed
attempt (no answer) adds the tokens it reported, usually none, so a dead endpoint shows 0
tokens; but its cost is unknown, since a provider may bill a request it never answered
(one cut off mid-generation). A request the server refused for its form (a structured-
output level or a decoding parameter it does not take: negotiation) adds its tokens if
it reported any and its time to the LLM time; it costs nothing unless it reported tokens
(turned down before generation, it is not billed). Negotiation happens once per endpoint
and process, in whichever episode calls first: the refused requests' counts are the only
columns that depend on the scheduling. ``llm_calls`` counts calls (a call's retries and
repairs are attempts of it), ``llm_requests`` every request sent (every attempt: retries
and refused forms included), ``llm_refused_requests`` the refused ones;
``llm_failed_calls`` counts only calls that ended with no answer, so negotiation that
ended in an answer is no failure. ``llm_unpriced_requests`` counts requests (attempts)
whose cost is unknown (``llm_unpriced_calls`` in scores files written before the name
said so: :func:`~skyvln_eval.metrics.scores_io.read_scores` reads it under this one).
``llm_latency_s`` is the time of every request (answered, failed and refused), queueing
excluded. ``llm_cost_lower_usd`` is a known lower bound where only failed
attempts are unpriced (a single HTTP 429 would otherwise leave nothing of a backend's
cost) and some attempt that was not a refusal is priced (else nothing shows the model
has a price): Table II shows it as "≥x" in place of "n/a".
An episode without calls costs a known 0.
Rates (call failure rate, fallback rate) are NaN for an episode with nothing to rate (no
call, no decision); over episodes they are pooled (failed calls of all calls: see
:data:`~skyvln_eval.metrics.aggregate.POOLED_RATES`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import pandas as pd

from skyvln_eval.llm_records import ModuleFailure, fallback_steps
from skyvln_eval.metrics.records import KEY_COLUMNS, EpisodeResult, LlmCall

#: Per-episode LLM columns and their units.
COST_COLUMNS: dict[str, str] = {
    "llm_calls": "calls",
    "llm_requests": "requests",
    "llm_refused_requests": "requests",
    "llm_failed_calls": "calls",
    "llm_call_failure_rate": "fraction",
    "llm_parse_failures": "answers",
    "llm_repairs": "calls",
    "llm_cached_calls": "calls",
    "llm_prompt_tokens": "tokens",
    "llm_completion_tokens": "tokens",
    "llm_cost_usd": "USD",
    "llm_cost_lower_usd": "USD",
    "llm_unpriced_requests": "requests",
    "llm_latency_s": "s",
    "llm_queue_s": "s",
    "decisions": "decisions",
    "fallback_decisions": "decisions",
    "fallback_rate": "fraction",
    "module_failures": "failures",
}
#: Columns whose mean is unknown (NaN, "n/a") as soon as one episode's value is.
UNKNOWN_IF_ANY_UNKNOWN = frozenset(
    {
        "llm_cost_usd",
        "llm_cost_lower_usd",
        "llm_prompt_tokens",
        "llm_completion_tokens",
        "llm_latency_s",  # known unless no one recorded the calls (predictions from elsewhere)
        "llm_queue_s",
    }
)


def _sum_known(values: Sequence[float | int | None]) -> float:
    """The sum, or NaN if any value is unknown."""
    return math.nan if any(v is None for v in values) else float(sum(v for v in values if v))


def _reported(call: LlmCall, tokens: int | None) -> int | None:
    """An attempt's token count: unknown only for an answered attempt that reported none (a
    failed or refused one that reported none adds 0; one that reported some adds them)."""
    return 0 if tokens is None and not call.answered else tokens


def _cost_lower_bound(calls: Sequence[LlmCall]) -> float:
    """What the calls cost at least: the priced attempts' sum, when only attempts without
    an answer (failed or refused, no token count: a provider may or may not bill them) are
    unpriced; NaN when an answered attempt is (no price for the model, or no token count),
    and when no attempt is priced at all. A record does not say whether its model has a
    price, and an unpriced failure looks the same either way: without one priced attempt
    nothing shows there is a price, so a model without one whose calls all failed would
    show a "known" 0 (a refusal, which costs 0 whatever the price, shows nothing either).
    No calls at all cost a known 0."""
    if any(c.cost_usd is None and c.answered for c in calls):
        return math.nan
    priced = [c.cost_usd for c in calls if c.cost_usd is not None]
    # A refusal costs 0 whether or not the model has a price: no evidence of one.
    if calls and not any(c.cost_usd is not None and c.outcome != "refused" for c in calls):
        return math.nan
    return float(sum(priced))


def call_totals(
    calls: Sequence[LlmCall], failures: Sequence[ModuleFailure] = (), decisions: int = 0
) -> dict[str, float]:
    """Totals over some calls (and the decisions they served), keyed as :data:`COST_COLUMNS`."""
    finals = [c for c in calls if c.final]
    failed = sum(c.outcome == "failed" for c in finals)
    fallbacks = fallback_steps(failures)
    return {
        "llm_calls": float(len(finals)),
        "llm_requests": float(len(calls)),
        "llm_refused_requests": float(sum(c.outcome == "refused" for c in calls)),
        "llm_failed_calls": float(failed),
        "llm_call_failure_rate": failed / len(finals) if finals else math.nan,
        "llm_parse_failures": float(sum(c.outcome == "invalid" for c in calls)),
        "llm_repairs": float(sum(c.repair for c in finals)),
        "llm_cached_calls": float(sum(c.cached for c in finals)),
        "llm_prompt_tokens": _sum_known([_reported(c, c.prompt_tokens) for c in calls]),
        "llm_completion_tokens": _sum_known([_reported(c, c.completion_tokens) for c in calls]),
        "llm_cost_usd": _sum_known([c.cost_usd for c in calls]),
        "llm_cost_lower_usd": _cost_lower_bound(calls),
        "llm_unpriced_requests": float(sum(c.cost_usd is None for c in calls)),
        "llm_latency_s": float(sum(c.latency_s for c in calls)),
        "llm_queue_s": float(sum(c.queue_s for c in calls)),
        "decisions": float(decisions),
        "fallback_decisions": float(len(fallbacks)),
        "fallback_rate": len(fallbacks) / decisions if decisions else math.nan,
        "module_failures": float(len(failures)),
    }


def episode_totals(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """One row per result with its LLM totals (:data:`COST_COLUMNS` only: the scores'
    columns; zeros and known costs when it made no call; empty, i.e. unknown, where no
    one recorded its calls: ``llm_use_recorded``)."""
    unknown = dict.fromkeys(COST_COLUMNS, math.nan)
    rows = [
        call_totals(r.llm_calls, r.module_failures, r.decisions) if r.llm_use_recorded else unknown
        for r in results
    ]
    return pd.DataFrame(rows, columns=list(COST_COLUMNS))


def episode_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """One row per result: which episode (the scores' key columns, to join with them)
    and its LLM totals (:func:`episode_totals`)."""
    ids = pd.DataFrame([r.key for r in results], columns=list(KEY_COLUMNS), dtype=object)
    return pd.concat([ids, episode_totals(results)], axis=1)


def module_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """One row per (result, agent module that called or failed), with that module's totals.

    Decisions belong to the episode, not to a module: a row's ``decisions`` are its
    episode's, its ``fallback_decisions`` those that fell back for this module's failures,
    and its ``fallback_rate`` their share of the episode's decisions."""
    rows = []
    for r in results:
        calls: dict[str, list[LlmCall]] = {}
        failures: dict[str, list[ModuleFailure]] = {}
        for call in r.llm_calls:
            calls.setdefault(call.module, []).append(call)
        for failure in r.module_failures:
            failures.setdefault(failure.module, []).append(failure)
        for module in sorted(set(calls) | set(failures)):
            models = sorted({f"{c.backend}:{c.model}" for c in calls.get(module, [])})
            totals = call_totals(calls.get(module, []), failures.get(module, []), r.decisions)
            rows.append(
                {
                    **dict(zip(KEY_COLUMNS, r.key, strict=True)),
                    "module": module,
                    "models": ",".join(models),
                    **totals,
                }
            )
    columns = [*KEY_COLUMNS, "module", "models", *COST_COLUMNS]
    return pd.DataFrame(rows, columns=columns)


_SUMMED = [
    c for c in COST_COLUMNS if c not in ("llm_call_failure_rate", "fallback_rate", "decisions")
]


def summarise_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """Per (system, split, module): totals, per-episode means and latency per call.

    Per-episode means divide by every episode of the group, including those in which the
    module made no call, so modules compare on the same footing. Module ``"all"`` sums
    every module. A total with an unknown part is unknown (NaN), never a partial sum.
    """
    per_module = module_costs(results)
    episodes = pd.DataFrame(
        [{"system": r.system, "split": r.split, "mode": r.mode} for r in results],
        columns=["system", "split", "mode"],
    )
    if per_module.empty:
        return pd.DataFrame(columns=["system", "split", "mode", "module", "episodes", *_SUMMED])
    totals = per_module.copy()
    totals["module"] = "all"
    both = pd.concat([per_module, totals], ignore_index=True)
    keys = ["system", "split", "mode", "module"]
    summed = (
        both.groupby(keys, sort=True)[_SUMMED]
        .agg(lambda column: column.sum(skipna=False))
        .reset_index()
    )
    counts = episodes.value_counts(["system", "split", "mode"]).rename("episodes").reset_index()
    out = summed.merge(counts, on=["system", "split", "mode"], how="left")
    for column in _SUMMED:
        out[f"{column}_per_episode"] = out[column] / out["episodes"]
    calls = out["llm_calls"].where(out["llm_calls"] > 0)
    out["latency_per_call_s"] = (out["llm_latency_s"] / calls).fillna(0.0)
    out["call_failure_rate"] = (out["llm_failed_calls"] / calls).fillna(0.0)
    return out
