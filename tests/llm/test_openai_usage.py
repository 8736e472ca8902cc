"""What an OpenAI-compatible server's usage object becomes in the call records and the
cost (from an audit against a fake server with real endpoints' documented usage): prompt
tokens served from OpenAI's prompt cache, a reasoning model's hidden tokens, Ollama's
``prompt_tokens: 0``."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.llm import GenerationConfig, Message
from skyvln_eval.llm.cache import ResponseCache
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer
from skyvln_eval.llm.prices import DEFAULT_PRICES_PATH, Price, PriceTable, load_prices
from skyvln_eval.llm_records import LlmCall
from tests.llm.loopback_clients import loopback_client

HELLO = [Message("system", "You answer in JSON."), Message("user", "Say hello.")]
CONFIG = GenerationConfig(timeout_s=5.0)
GREETING = '{"greeting": "hi"}'
#: OpenAI's usage of a call whose prompt its prompt cache mostly served.
CACHED_USAGE: dict[str, Any] = {
    "prompt_tokens": 10000,
    "completion_tokens": 100,
    "total_tokens": 10100,
    "prompt_tokens_details": {"cached_tokens": 9984},
}


def _priced(server: LoopbackOpenAIServer, price: Price) -> PriceTable:
    return PriceTable({f"openai:fake-model@{server.base_url}": price})


def test_prompt_tokens_from_the_prompt_cache_are_recorded_and_priced_at_a_discount() -> None:
    gpt_4o_mini = Price(0.15, 0.60, cached_input_usd_per_mtok=0.075)
    with LoopbackOpenAIServer([answer(GREETING, usage=CACHED_USAGE)]) as server:
        client = loopback_client(server, 1, prices=_priced(server, gpt_4o_mini))
        [record] = client.call("motion", HELLO, CONFIG).records
    assert (record.prompt_tokens, record.cached_prompt_tokens) == (10000, 9984)
    # 16 uncached x 0.15 + 9984 cached x 0.075 + 100 x 0.60, per million: what OpenAI bills
    # (the whole prompt at the full price was 0.00156).
    assert record.cost_usd == pytest.approx(0.0008112)


def test_cached_tokens_without_a_cached_price_are_charged_in_full_and_said_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with LoopbackOpenAIServer([answer(GREETING, usage=CACHED_USAGE)]) as server:
        client = loopback_client(server, 1, prices=_priced(server, Price(0.15, 0.60)))
        with caplog.at_level(logging.WARNING):
            [record] = client.call("motion", HELLO, CONFIG).records
    assert record.cached_prompt_tokens == 9984
    assert record.cost_usd == pytest.approx(0.00156)  # an upper bound, no made-up discount
    assert "no cached_input price" in caplog.text and "upper bound" in caplog.text


def test_the_shipped_prices_have_openais_cached_input_prices() -> None:
    shipped = load_prices(DEFAULT_PRICES_PATH).prices
    cached = {k: shipped[k].cached_input_usd_per_mtok for k in shipped}
    assert cached["openai:gpt-4o"] == cached["openai:gpt-4o-2024-08-06"] == 1.25
    assert cached["openai:gpt-4o-mini"] == 0.075
    assert cached["openai:gpt-4-turbo"] is cached["openai:gpt-3.5-turbo"] is None


def test_a_price_entry_with_an_unknown_field_is_refused(tmp_path: Path) -> None:
    table = tmp_path / "prices.yaml"
    table.write_text(
        "format: skyvln-eval/llm-prices\nversion: 1\nusd_per_million_tokens:\n"
        "  openai:m: {input: 1.0, output: 2.0, cache_input: 0.5}\n"
    )
    with pytest.raises(Exception, match="cached_input"):
        load_prices(table)


def test_a_cached_answer_keeps_its_cached_prompt_tokens_and_cost(tmp_path: Path) -> None:
    price = Price(0.15, 0.60, cached_input_usd_per_mtok=0.075)
    cache = ResponseCache(tmp_path / "cache.sqlite")
    with LoopbackOpenAIServer([answer(GREETING, usage=CACHED_USAGE)]) as server:
        client = loopback_client(server, 1, prices=_priced(server, price))
        client.cache = cache
        first = client.call("motion", HELLO, CONFIG).records[0]
        again = client.call("motion", HELLO, CONFIG).records[0]
    assert again.cached and again.cached_prompt_tokens == 9984
    assert again.cost_usd == first.cost_usd


def test_reasoning_tokens_are_recorded() -> None:
    usage = {
        "prompt_tokens": 1800,
        "completion_tokens": 900,
        "completion_tokens_details": {"reasoning_tokens": 870},
    }
    budget = GenerationConfig(timeout_s=5.0, max_tokens=1024)
    with LoopbackOpenAIServer([answer(GREETING, usage=usage)]) as server:
        [record] = loopback_client(server, 1).call("motion", HELLO, budget).records
    assert (record.completion_tokens, record.reasoning_tokens) == (900, 870)


def test_a_completion_longer_than_its_budget_is_no_count() -> None:
    # An audit's server said 90 million tokens for a 1024-token budget: $8910 an episode,
    # ranked in Table II. The model cannot write more than the request let it.
    usage = {"prompt_tokens": 1800, "completion_tokens": 90_000_000}
    fine = {"prompt_tokens": 1800, "completion_tokens": 1024}
    with LoopbackOpenAIServer([answer(GREETING, usage=u) for u in (usage, fine)]) as server:
        client = loopback_client(server, 1, _priced(server, Price(1.0, 2.0)))
        budget = GenerationConfig(max_tokens=1024)
        [record] = client.call("motion", HELLO, budget).records
        [at_budget] = client.call("subgoals", HELLO, budget).records
    assert (record.prompt_tokens, record.completion_tokens, record.cost_usd) == (1800, None, None)
    assert at_budget.completion_tokens == 1024 and at_budget.cost_usd is not None


def test_a_prompt_of_zero_tokens_leaves_the_completion_count_known() -> None:
    # Ollama reports prompt_tokens 0 when its cache served the prompt; its completion
    # count is right. Only the prompt count is unknown (and so is the cost).
    usage = {"prompt_tokens": 0, "completion_tokens": 37, "total_tokens": 37}
    with LoopbackOpenAIServer([answer(GREETING, usage=usage)]) as server:
        [record] = loopback_client(server, 1).call("motion", HELLO, CONFIG).records
    assert (record.prompt_tokens, record.completion_tokens, record.cost_usd) == (None, 37, None)


def test_records_round_trip_the_new_counts_and_old_records_still_read() -> None:
    call = LlmCall(
        module="motion", backend="openai", model="m", cached_prompt_tokens=9, reasoning_tokens=3
    )
    assert LlmCall.from_json_dict(call.to_json_dict()) == call
    old = call.to_json_dict()
    del old["cached_prompt_tokens"], old["reasoning_tokens"]
    read = LlmCall.from_json_dict(old)
    assert (read.cached_prompt_tokens, read.reasoning_tokens) == (None, None)
