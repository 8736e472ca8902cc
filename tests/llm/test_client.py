"""Registry, retries, concurrency limit, prices and per-call accounting."""

from __future__ import annotations

import random
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import pytest

from skyvln_eval.errors import ConfigError, LLMTransientError, UnknownNameError
from skyvln_eval.llm import (
    Completion,
    GenerationConfig,
    LLMBackend,
    LLMClient,
    Message,
    RetryPolicy,
    create_backend,
    load_prices,
    register_backend,
    registry,
)
from skyvln_eval.llm.prices import price_key
from skyvln_eval.llm.simple import ScriptedBackend
from skyvln_eval.llm_records import LlmCall
from tests.conftest import REPO

PROMPT = [Message("user", "hi")]


def test_unknown_backends_get_a_did_you_mean() -> None:
    with pytest.raises(UnknownNameError, match="Did you mean 'openai'"):
        create_backend("opneai:gpt-4o")


def test_importing_the_llm_package_does_not_import_openai() -> None:
    code = "import sys, skyvln_eval.llm, skyvln_eval.llm.rule; print('openai' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "False"


def test_a_registered_backend_is_created_like_the_built_in_ones(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The registry is the process's: restored afterwards, so tests that list the known
    # backends in the same worker do not see "echo".
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))

    class Echo(LLMBackend):
        name = "echo"
        kind = "scripted"

        def __init__(self, model: str | None = None) -> None:
            self.model = model or "plain"

        def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
            return Completion(messages[-1].text, self.name, self.model)

    register_backend("echo", Echo)
    backend = create_backend("echo:loud")
    assert backend.model == "loud" and backend.generate(PROMPT, GenerationConfig()).text == "hi"


def test_backoff_grows_exponentially_with_bounded_jitter() -> None:
    policy = RetryPolicy(initial_delay_s=1.0, multiplier=2.0, max_delay_s=5.0, jitter=0.25)
    rng = random.Random(0)
    fault = LLMTransientError("server error")
    delays = [policy.delay_s(k, fault, rng) for k in range(5)]
    for k, delay in enumerate(delays):
        base = min(2.0**k, 5.0)
        assert base <= delay <= base * 1.25
    assert policy.delay_s(0, LLMTransientError("429", retry_after_s=3.0), rng) == 3.0
    assert policy.delay_s(0, LLMTransientError("429", retry_after_s=999.0), rng) == 60.0


def test_the_concurrency_limit_holds_across_threads() -> None:
    running = 0
    peak = 0
    lock = threading.Lock()

    def slow(messages: Sequence[Message]) -> str:
        nonlocal running, peak
        with lock:
            running += 1
            peak = max(peak, running)
        time.sleep(0.05)
        with lock:
            running -= 1
        return "ok"

    client = LLMClient(ScriptedBackend([slow] * 8), max_concurrency=2)
    threads = [
        threading.Thread(target=client.call, args=("m", PROMPT, GenerationConfig()))
        for _ in range(8)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert peak == 2


def test_a_model_name_is_priced_only_on_its_vendors_server(tmp_path: Path) -> None:
    """A local server that calls its model "gpt-4o-mini" is not OpenAI: its calls are not
    priced at OpenAI's rates, only under the server's own key, which a user may add."""
    vendor = {"backend": "openai", "model": "gpt-4o-mini", "base_url": "https://api.openai.com/v1/"}
    local = {**vendor, "base_url": "http://127.0.0.1:8080/v1"}
    assert price_key(vendor) == "openai:gpt-4o-mini"
    assert price_key(local) == "openai:gpt-4o-mini@http://127.0.0.1:8080/v1"
    assert price_key({"backend": "rule", "model": ""}) == "rule:"
    shipped = load_prices()
    assert shipped.cost_usd(price_key(vendor), 1_000_000, 0) == pytest.approx(0.15)
    assert shipped.cost_usd(price_key(local), 1_000_000, 0) is None
    table = tmp_path / "prices.yaml"
    table.write_text(
        "format: skyvln-eval/llm-prices\nversion: 1\nusd_per_million_tokens:\n"
        "  openai:gpt-4o-mini@http://127.0.0.1:8080/v1: {input: 0.0, output: 0.0}\n"
    )
    assert load_prices(table).cost_usd(price_key(local), 1_000_000, 0) == 0.0


def test_costs_come_from_the_price_table(tmp_path: Path) -> None:
    prices = load_prices()  # the shipped table
    assert prices.cost_usd("openai:gpt-4o", 1_000_000, 0) == pytest.approx(2.5)
    assert prices.cost_usd("openai:not-listed", 10, 10) is None
    table = tmp_path / "prices.yaml"
    table.write_text(
        "format: skyvln-eval/llm-prices\nversion: 1\nusd_per_million_tokens:\n"
        "  scripted:m: {input: 1.0, output: 2.0}\n"
    )
    client = LLMClient(ScriptedBackend(["x" * 40], model="m"), prices=load_prices(table))
    record = client.call("motion", [Message("user", "y" * 400)], GenerationConfig()).records[0]
    assert (record.prompt_tokens, record.completion_tokens) == (100, 10)
    assert record.cost_usd == 0.0  # scripted, random and rule backends never cost money
    bad = tmp_path / "bad.yaml"
    header = "format: skyvln-eval/llm-prices\nversion: 1\nusd_per_million_tokens:\n"
    bad.write_text(header + "  a:b: {input: -1, output: 2}\n")
    with pytest.raises(ConfigError, match=r"a:b\.input"):
        load_prices(bad)


def test_call_records_have_exactly_the_agreed_fields() -> None:
    config = GenerationConfig(temperature=0.3, max_tokens=77)
    record = LLMClient(ScriptedBackend(["x"])).call("hsd_rank", PROMPT, config).records[0]
    assert list(record.to_json_dict()) == [
        "module",
        "backend",
        "model",
        "outcome",
        "error",
        "attempt",
        "final",
        "repair",
        "prompt_tokens",
        "completion_tokens",
        "cached_prompt_tokens",
        "reasoning_tokens",
        "cost_usd",
        "latency_s",
        "queue_s",
        "cached",
        "finish_reason",
        "temperature",
        "max_tokens",
        "structured_output",
        "server_defaults",
    ]
    assert record.module == "hsd_rank" and record.error is None and record.cached is False
    assert (record.outcome, record.attempt, record.final) == ("ok", 1, True)
    assert (record.temperature, record.max_tokens, record.finish_reason) == (0.3, 77, "stop")
    assert LlmCall.from_json_dict(record.to_json_dict()) == record


def test_every_attempt_is_numbered_and_only_the_last_ends_the_call() -> None:
    script: list[object] = [LLMTransientError("HTTP 500"), LLMTransientError("HTTP 502"), "x"]
    client = LLMClient(
        ScriptedBackend(script),  # type: ignore[arg-type]
        retry=RetryPolicy(initial_delay_s=0.0, jitter=0.0),
        sleep=lambda _: None,
    )
    records = client.call("motion", PROMPT, GenerationConfig()).records
    assert [(r.attempt, r.final, r.outcome) for r in records] == [
        (1, False, "failed"),
        (2, False, "failed"),
        (3, True, "ok"),
    ]
    assert records[0].cost_usd == 0.0  # a scripted backend costs nothing, failed or not


def test_a_failed_attempt_of_a_real_backend_has_unknown_cost_not_zero() -> None:
    class Down(LLMBackend):
        name = "down"
        kind = "llm"
        model = "m"

        def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
            raise LLMTransientError("HTTP 503")

    client = LLMClient(Down(), retry=RetryPolicy(max_attempts=2, initial_delay_s=0.0))
    result = client.call("motion", PROMPT, GenerationConfig())
    assert result.completion is None and [r.final for r in result.records] == [False, True]
    assert all(r.cost_usd is None and r.outcome == "failed" for r in result.records)
    assert all(r.prompt_tokens is None for r in result.records)
