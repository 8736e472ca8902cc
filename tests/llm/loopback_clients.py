"""LLM clients of the loopback OpenAI-compatible server, for the tests of what a server's
answers become in the call records."""

from __future__ import annotations

from pathlib import Path

from skyvln_eval.llm import LLMClient, RetryPolicy, create_backend
from skyvln_eval.llm.loopback import LoopbackOpenAIServer
from skyvln_eval.llm.prices import PriceTable, load_prices


def loopback_client(
    server: LoopbackOpenAIServer,
    attempts: int = 3,
    prices: PriceTable | None = None,
    **options: object,
) -> LLMClient:
    """The ``openai`` backend's client of ``server`` (model ``fake-model``), retrying at
    once (no sleeps), with ``prices`` if given; ``options`` go to the backend."""
    backend = create_backend("openai:fake-model", base_url=server.base_url, **options)
    retry = RetryPolicy(max_attempts=attempts, initial_delay_s=0.0, max_delay_s=0.0)
    return LLMClient(backend, retry=retry, prices=prices or PriceTable(), sleep=lambda _: None)


def fake_model_prices(server: LoopbackOpenAIServer, folder: Path) -> PriceTable:
    """A price table (written in ``folder``) pricing ``fake-model`` on ``server`` at 1 USD
    per million prompt tokens and 2 per million completion tokens."""
    table = folder / "prices.yaml"
    table.write_text(
        "format: skyvln-eval/llm-prices\nversion: 1\nusd_per_million_tokens:\n"
        f"  openai:fake-model@{server.base_url}: {{input: 1.0, output: 2.0}}\n"
    )
    return load_prices(table)
