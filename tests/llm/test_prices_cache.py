"""The price table is parsed once per process while its file is unchanged."""

from __future__ import annotations

from pathlib import Path

from skyvln_eval.llm.prices import load_prices

TABLE = """format: skyvln-eval/llm-prices
version: 1
as_of: "2025-01-01"
usd_per_million_tokens:
  "openai:test-model": {{input: {price}, output: 2.0}}
"""


def test_an_unchanged_table_is_parsed_once_and_a_changed_one_again(tmp_path: Path) -> None:
    file = tmp_path / "prices.yaml"
    file.write_text(TABLE.format(price=1.0))
    first = load_prices(file)
    assert load_prices(file) is first
    file.write_text(TABLE.format(price=1.25))
    changed = load_prices(file)
    assert changed is not first
    assert changed.prices["openai:test-model"].input_usd_per_mtok == 1.25
