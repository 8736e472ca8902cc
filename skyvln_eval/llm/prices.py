"""Price table of LLM calls (``configs/llm/prices.yaml``) and the cost of one call."""

from __future__ import annotations

import functools
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import yaml

from skyvln_eval.errors import ConfigError, FormatVersionError
from skyvln_eval.fileio import load_yaml

log = logging.getLogger(__name__)

PRICES_FORMAT: Final = "skyvln-eval/llm-prices"
PRICES_VERSION: Final = 1
#: The table shipped with the repository; ``$SKYVLN_EVAL_PRICES`` points elsewhere.
#: Shipped inside the package (``skyvln_eval/configs``, also reachable as ``configs/`` in
#: a checkout), so an installed toolkit prices calls too.
DEFAULT_PRICES_PATH: Final = Path(__file__).resolve().parents[1] / "configs" / "llm" / "prices.yaml"
#: The vendors' own servers: a price listed as ``<backend>:<model>`` is the vendor's
#: price, for calls to this server. Any other server (a local llama.cpp that calls its
#: model "gpt-4o-mini", a proxy, another provider) is priced only under its own key,
#: ``<backend>:<model>@<base_url>``: a model's name does not say who serves it at what cost.
VENDOR_SERVERS: Final[Mapping[str, str]] = {"openai": "https://api.openai.com/v1"}


def price_key(identity: Mapping[str, Any]) -> str:
    """The price table's key of a backend's calls, from its ``identity()``: ``backend:model``
    on the vendor's server (or for a backend without one), else ``backend:model@base_url``."""
    backend, model = str(identity["backend"]), str(identity["model"])
    server = str(identity.get("base_url") or "").rstrip("/")
    if not server or server == VENDOR_SERVERS.get(backend):
        return f"{backend}:{model}"
    return f"{backend}:{model}@{server}"


@dataclass(frozen=True)
class Price:
    """US dollars per million prompt (input) and completion (output) tokens, and per
    million prompt tokens a provider's prompt cache served (``cached_input``; ``None``:
    no discount known, they cost ``input``)."""

    input_usd_per_mtok: float
    output_usd_per_mtok: float
    cached_input_usd_per_mtok: float | None = None

    def cost_usd(
        self, prompt_tokens: int, completion_tokens: int, cached_prompt_tokens: int = 0
    ) -> float:
        """The cost of a call; ``cached_prompt_tokens`` (part of ``prompt_tokens``) at the
        cached-input price when there is one, else at the full input price (an upper
        bound: no provider charges cached tokens more)."""
        cached_price = self.cached_input_usd_per_mtok
        cached = 0 if cached_price is None else min(cached_prompt_tokens, prompt_tokens)
        return (
            (prompt_tokens - cached) * self.input_usd_per_mtok
            + cached * (cached_price or 0.0)
            + completion_tokens * self.output_usd_per_mtok
        ) / 1e6


_WARNED_UNPRICED: set[str] = set()
_WARNED_NO_CACHED_PRICE: set[str] = set()


@dataclass(frozen=True)
class PriceTable:
    """Prices by :func:`price_key` (``"<backend>:<model>"`` for the vendor's server,
    ``"<backend>:<model>@<base_url>"`` for any other); ``as_of`` says when they were checked."""

    prices: Mapping[str, Price] = field(default_factory=dict)
    as_of: str = ""

    def cost_usd(
        self,
        key: str,
        prompt_tokens: int,
        completion_tokens: int,
        cached_prompt_tokens: int | None = None,
    ) -> float | None:
        """Cost of one call priced under ``key`` (:func:`price_key`), or ``None`` when the
        table has no such key (logged once). ``cached_prompt_tokens`` of the prompt are
        priced at the key's ``cached_input`` price; without one, at the full input price
        (an upper bound, logged once per key)."""
        price = self.prices.get(key)
        if price is None:
            if key not in _WARNED_UNPRICED:  # once per process: agents are built per episode
                _WARNED_UNPRICED.add(key)
                elsewhere = "@" in key.partition(":")[2]
                log.warning(
                    "no price for %s in the price table: its cost_usd is recorded as unknown%s",
                    key,
                    " (a server other than the vendor's is priced only under its own key)"
                    if elsewhere
                    else "",
                )
            return None
        cached = cached_prompt_tokens or 0
        if (
            cached
            and price.cached_input_usd_per_mtok is None
            and key not in _WARNED_NO_CACHED_PRICE
        ):
            _WARNED_NO_CACHED_PRICE.add(key)
            log.warning(
                "%s reports prompt tokens served from its prompt cache, but the price table "
                "has no cached_input price for it: they are charged at the full input price "
                "(its cost_usd is an upper bound)",
                key,
            )
        return price.cost_usd(prompt_tokens, completion_tokens, cached)


def _number(value: Any, where: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value < 0
    ):
        raise ConfigError(f"{where} must be a non-negative number, got {value!r}")
    return float(value)


def load_prices(path: str | Path | None = None) -> PriceTable:
    """Read a price table: ``path``, else ``$SKYVLN_EVAL_PRICES``, else the shipped one.

    An absent default table gives an empty one (every cost unknown); a named file that is
    missing or malformed raises :class:`ConfigError` naming the file and field. A table is
    parsed once per process while its file is unchanged (agents are built per episode).
    """
    chosen = path or os.environ.get("SKYVLN_EVAL_PRICES")
    file = Path(chosen) if chosen else DEFAULT_PRICES_PATH
    if not file.is_file():
        if chosen:
            raise ConfigError(f"price table {file} not found")
        log.warning("price table %s not found: every cost_usd is recorded as unknown", file)
        return PriceTable()
    stat = file.stat()
    return _parsed_prices(str(file.resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=8)
def _parsed_prices(path: str, mtime_ns: int, size: int) -> PriceTable:
    """The table in ``path`` (its modification time and size key the cache)."""
    file = Path(path)
    try:
        data = load_yaml(file.read_text(encoding="utf-8"), file)
    except yaml.YAMLError as error:
        raise ConfigError(f"price table {file} is not valid YAML: {error}") from error
    if not isinstance(data, dict) or data.get("format") != PRICES_FORMAT:
        raise ConfigError(f"price table {file}: 'format' must be {PRICES_FORMAT!r}")
    if data.get("version") != PRICES_VERSION:
        raise FormatVersionError(
            str(file), data.get("version"), PRICES_VERSION, "Update the file's layout."
        )
    table = data.get("usd_per_million_tokens")
    if not isinstance(table, dict):
        raise ConfigError(f"price table {file}: 'usd_per_million_tokens' must be a mapping")
    prices = {}
    for spec, entry in table.items():
        where = f"price table {file}, usd_per_million_tokens.{spec}"
        if (
            not isinstance(entry, dict)
            or not {"input", "output"} <= set(entry)
            or not set(entry) <= {"input", "output", "cached_input"}
        ):
            raise ConfigError(
                f"{where} must have 'input' and 'output' (and optionally 'cached_input')"
            )
        cached = entry.get("cached_input")
        prices[str(spec)] = Price(
            _number(entry["input"], f"{where}.input"),
            _number(entry["output"], f"{where}.output"),
            None if cached is None else _number(cached, f"{where}.cached_input"),
        )
    return PriceTable(prices=prices, as_of=str(data.get("as_of", "")))
