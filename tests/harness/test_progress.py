"""The progress bar's LLM cost: a known total, a known zero, or n/a, never a $0 it does not know."""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
from rich.console import Console

from skyvln_eval.harness.progress import RichRunProgress
from skyvln_eval.metrics import EpisodeResult, LlmCall
from tests.metrics.helpers import result, square

GT = [square(0, 0), square(100, 0)]


def flown(*costs: float | None) -> EpisodeResult:
    """An episode that flew, with one call per cost (None: not priced)."""
    calls = tuple(LlmCall(module="action", backend="openai", model="m", cost_usd=c) for c in costs)
    return result([GT[0], square(100, 0)], GT, llm_calls=calls)


def refused() -> EpisodeResult:
    """The row of an episode whose first call was refused (HTTP 401): it raised out of its
    loop, so it has no view, and the refused attempt, whose cost is not known."""
    call = LlmCall(
        module="subgoals", backend="openai", model="m", outcome="failed", error="HTTP 401"
    )
    return result(
        np.zeros((0, 4, 2)), GT, status="error", llm_calls=(call,), extra={"fatal": "HTTP 401"}
    )


def shown(*results: EpisodeResult) -> str:
    progress = RichRunProgress(Console(file=io.StringIO(), width=200))
    progress.start("run", total=len(results) + 1, already_done=0)
    for r in results:
        progress.episode_done(r, success=True)
    stats = progress._stats()
    progress.finish([])
    return stats


def test_a_run_stopped_before_any_priced_call_shows_no_cost() -> None:
    assert "LLM n/a" in shown(refused())
    assert "LLM n/a" in shown()  # nothing finished, nothing priced yet
    assert "LLM n/a" in shown(flown(0.002), refused())  # what the refused one cost is unknown


def test_a_known_cost_is_shown_and_a_known_zero_stays_zero() -> None:
    assert "LLM $0.0035" in shown(flown(0.002, 0.001), flown(0.0005))
    assert "LLM $0.0000" in shown(flown(0.0, 0.0), flown(0.0))  # the rule stand-in, a free model
    assert "LLM $0.0000" in shown(flown())  # an agent that calls no LLM
    assert "LLM n/a" in shown(flown(0.002), flown(None), flown(0.001))  # once unknown, stays
    # Replayed from the response cache: the cost of the call that made it, said to be so
    # (an audit saw a run of cached answers only shown as money spent).
    fresh, replayed = flown(0.002, 0.001).llm_calls
    cached = result([GT[0], square(100, 0)], GT, llm_calls=(fresh, replace(replayed, cached=True)))
    assert "LLM $0.0030 ($0.0010 of it from the cache)" in shown(cached)
    assert "from the cache" not in shown(flown(0.002))


def test_the_live_sr_leaves_the_oracles_episodes_out() -> None:
    # A reproduction runs the ground-truth oracle next to the agents: pooled in, it lifted
    # the live SR (an audit read 44.9% where the agents' own was 38.3%).
    progress = RichRunProgress(Console(file=io.StringIO(), width=200))
    progress.start("run", total=3, already_done=0)
    progress.episode_done(flown(), success=False)
    progress.episode_done(result([GT[0], GT[1]], GT, extra={"oracle": True}), success=True)
    assert "SR   0.0%" in progress._stats()  # the agent's failure alone
    progress.finish([])


def test_a_resumed_run_with_nothing_left_says_so() -> None:
    # It showed "SR n/a | LLM n/a", as if the episodes had no ground truth or cost.
    progress = RichRunProgress(Console(file=io.StringIO(), width=200))
    progress.start("run", total=4, already_done=4)
    assert progress._stats() == "nothing left to run: every episode was recorded before"
    progress.finish([])


def test_a_resumed_run_s_live_sr_says_it_is_this_launch_s() -> None:
    # A --retry-failed launch showed "SR 0.0%" for a run standing at 1 ok of 3 (33%).
    progress = RichRunProgress(Console(file=io.StringIO(), width=200))
    progress.start("run", total=3, already_done=1)
    progress.episode_done(flown(), success=False)
    assert progress._stats().startswith("SR this launch   0.0%")
    progress.finish([])


def test_an_oracle_run_says_why_it_shows_no_success_rate() -> None:
    oracle = replace(flown(), extra={"oracle": True})
    assert "SR n/a (the oracle: a reference)" in shown(oracle, oracle)
    # Its ground truth exists: "no ground truth" is for episodes that have none.
    assert "SR 100.0%" in shown(oracle, flown())  # the agent's episode alone is scored
