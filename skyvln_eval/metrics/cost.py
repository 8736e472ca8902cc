"""Cost metrics: LLM calls, tokens, money and latency per episode and per agent module.

Inputs are the :class:`~skyvln_eval.metrics.records.LlmCall` records of each
:class:`~skyvln_eval.metrics.records.EpisodeResult`. Per-episode totals are columns of
the scores frame (``llm_cost_usd`` sums the priced calls; ``llm_unpriced_calls`` counts
calls whose model has no price, so a missing price is visible, not free);
:func:`module_costs` gives one row per (episode, module) and
:func:`summarise_costs` aggregates either over episodes. An episode without calls (a
rule-free baseline, a failed start) has zero cost, never a missing value.
"""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from skyvln_eval.metrics.records import EpisodeResult, LlmCall

#: Per-episode cost columns and their units.
COST_COLUMNS: dict[str, str] = {
    "llm_calls": "calls",
    "llm_cached_calls": "calls",
    "llm_failed_calls": "calls",
    "llm_prompt_tokens": "tokens",
    "llm_completion_tokens": "tokens",
    "llm_cost_usd": "USD",
    "llm_unpriced_calls": "calls",
    "llm_latency_s": "s",
}


def call_totals(calls: Sequence[LlmCall]) -> dict[str, float]:
    """Totals over some calls, keyed as :data:`COST_COLUMNS`."""
    return {
        "llm_calls": float(len(calls)),
        "llm_cached_calls": float(sum(c.cached for c in calls)),
        "llm_failed_calls": float(sum(c.error is not None for c in calls)),
        "llm_prompt_tokens": float(sum(c.prompt_tokens for c in calls)),
        "llm_completion_tokens": float(sum(c.completion_tokens for c in calls)),
        "llm_cost_usd": float(sum(c.cost_usd for c in calls if c.cost_usd is not None)),
        "llm_unpriced_calls": float(sum(c.cost_usd is None for c in calls)),
        "llm_latency_s": float(sum(c.latency_s for c in calls)),
    }


def episode_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """One row per result with its LLM totals (zeros when it made no call)."""
    zeros = call_totals(())
    rows = [call_totals(r.llm_calls) if r.llm_calls else zeros for r in results]
    return pd.DataFrame(rows, columns=list(COST_COLUMNS))


def module_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """One row per (result, agent module that called), with that module's totals."""
    rows = []
    for r in results:
        by_module: dict[str, list[LlmCall]] = {}
        for call in r.llm_calls:
            by_module.setdefault(call.module, []).append(call)
        for module in sorted(by_module):
            models = sorted({f"{c.backend}:{c.model}" for c in by_module[module]})
            rows.append(
                {
                    "system": r.system,
                    "split": r.split,
                    "mode": r.mode,
                    "episode_id": r.episode_id,
                    "module": module,
                    "models": ",".join(models),
                    **call_totals(by_module[module]),
                }
            )
    columns = ["system", "split", "mode", "episode_id", "module", "models", *COST_COLUMNS]
    return pd.DataFrame(rows, columns=columns)


def summarise_costs(results: Sequence[EpisodeResult]) -> pd.DataFrame:
    """Per (system, split, module): totals, per-episode means and mean latency per call.

    Per-episode means divide by every episode of the group, including those in which the
    module made no call, so modules compare on the same footing. Module ``"all"`` sums
    every module.
    """
    per_module = module_costs(results)
    episodes = pd.DataFrame(
        [{"system": r.system, "split": r.split, "mode": r.mode} for r in results],
        columns=["system", "split", "mode"],
    )
    if per_module.empty:
        return pd.DataFrame(
            columns=["system", "split", "mode", "module", "episodes", *COST_COLUMNS]
        )
    totals = per_module.copy()
    totals["module"] = "all"
    both = pd.concat([per_module, totals], ignore_index=True)
    keys = ["system", "split", "mode", "module"]
    summed = both.groupby(keys, sort=True)[list(COST_COLUMNS)].sum().reset_index()
    counts = episodes.value_counts(["system", "split", "mode"]).rename("episodes").reset_index()
    out = summed.merge(counts, on=["system", "split", "mode"], how="left")
    for column in COST_COLUMNS:
        out[f"{column}_per_episode"] = out[column] / out["episodes"]
    calls = out["llm_calls"].where(out["llm_calls"] > 0)
    out["latency_per_call_s"] = (out["llm_latency_s"] / calls).fillna(0.0)
    return out
