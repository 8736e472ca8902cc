"""The full SkyVLN agent on a real local model (llama.cpp + Gemma 3 270M), measured honestly.

The model is small and weak; what this checks is the protocol against a real server:
structured output negotiated down to what llama.cpp takes, every call answered, actions
parsed (with repair) rather than replaced by the fallback, and the counts on record.

It takes 4-7 minutes on 2 cores (254 s and 410 s measured: calls of 1,000-3,600 prompt
tokens, about 10-40 s each), more than a test run can spend, so it runs when
``$SKYVLN_EVAL_REAL_LLM_EPISODES`` is 1; the server's answers to the agent's calls are
checked on every run by ``test_local_server.py``, with short prompts.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm.local_server import MODEL_ALIAS, llm_settings
from skyvln_eval.metrics import read_results

EPISODES = 3
OPT_IN = "SKYVLN_EVAL_REAL_LLM_EPISODES"


@pytest.mark.skipif(
    os.environ.get(OPT_IN) != "1",
    reason=f"whole episodes on the real model take 4-7 min on 2 cores: set {OPT_IN}=1",
)
def test_the_full_agent_runs_on_a_real_local_model(
    local_llm_url: str, sample_dir: Path, tmp_path: Path
) -> None:
    llm = llm_settings(
        local_llm_url,
        timeout_s=300.0,
        budgets={"subgoals": 384, "hsd_describe": 96, "hsd_rank": 96, "motion": 160},
    )
    config = RunConfig(
        system="Full (Gemma 3 270M)",
        data=str(sample_dir),
        splits=("test_unseen",),
        limit=EPISODES,
        max_action_len=3,
        executor="serial",
        agent={"name": "skyvln", "top_k": 2, "llm": llm},  # type: ignore[arg-type]
    )
    report = run(config, tmp_path / "run")
    results = read_results(tmp_path / "run" / RESULTS_FILE)
    calls = [c for r in results for c in r.llm_calls]
    motion = [c for c in calls if c.module == "motion" and c.final]
    first_tries = [c for c in motion if not c.repair]
    fallbacks = sum(r.fallback_decisions for r in results)
    decisions = sum(r.decisions for r in results)
    print(
        f"\nreal model: {len(results)} episodes, statuses {report.statuses}, "
        f"structured output {report.structured_output}; {len(calls)} call attempts, "
        f"{sum(c.outcome == 'failed' for c in calls)} without an answer, "
        f"{sum(c.outcome == 'invalid' for c in calls)} unusable answers, "
        f"{sum(c.repair for c in calls)} repairs; motion: {len(first_tries)} decisions, "
        f"{decisions - fallbacks} parsed ({fallbacks} fallbacks); tokens "
        f"{sum(c.tokens or 0 for c in calls)}; LLM time {sum(c.latency_s for c in calls):.0f} s"
    )
    for r in results:
        print(f"  {r.episode_id}: {r.status}, {r.decisions} decisions, {r.llm_modules()}")
    assert len(results) == EPISODES and report.complete
    # Every call was answered by the real server (an unusable answer is still an answer).
    assert calls and all(c.outcome != "failed" for c in calls), [c.error for c in calls]
    # llama.cpp refuses the strict json_schema form; the schema rides on json_object.
    assert report.structured_output == {f"openai:{MODEL_ALIAS}": "json_object_schema"}
    # At least 90% of the motion decisions are parsed actions, not the fallback.
    assert decisions == len(first_tries) >= EPISODES
    assert decisions - fallbacks >= 0.9 * decisions
    # The records carry the counts: per module, calls, failures, repairs, tokens, time.
    for r in results:
        usage = r.llm_modules()
        assert usage["motion"]["calls"] >= r.decisions and usage["motion"]["llm_s"] > 0
        assert usage["motion"]["prompt_tokens"] > 0 and r.extra["wall_s"] > 0
        # Unpriced: every sent request's cost is unknown, not 0; only a refused form
        # (never generated, so never billed) costs a known 0.
        assert all((c.cost_usd == 0.0) == (c.outcome == "refused") for c in r.llm_calls)
        assert all(c.cost_usd is None for c in r.llm_calls if c.outcome != "refused")
