"""The response cache: keyed by model first and every decoding parameter; never fatal."""

from __future__ import annotations

import logging
import sqlite3
from dataclasses import replace
from pathlib import Path

import pytest

from skyvln_eval.errors import CacheMissError, ConfigError
from skyvln_eval.llm import (
    GenerationConfig,
    ImagePart,
    LLMClient,
    LLMConfig,
    Message,
    ResponseCache,
    build_client,
    cache_key,
    create_backend,
)
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer
from skyvln_eval.llm.simple import ScriptedBackend

PROMPT = [Message("user", "Which way?")]
CONFIG = GenerationConfig(timeout_s=2.0)


def _scripted_client(cache: ResponseCache, model: str, *answers: str) -> LLMClient:
    return LLMClient(ScriptedBackend(list(answers), model=model), cache=cache)


def test_the_same_prompt_to_two_models_makes_two_entries(tmp_path: Path) -> None:
    cache = ResponseCache(tmp_path / "cache.sqlite")
    a = _scripted_client(cache, "model-a", "north").call("motion", PROMPT, CONFIG)
    b = _scripted_client(cache, "model-b", "south").call("motion", PROMPT, CONFIG)
    assert (a.text, b.text) == ("north", "south")
    assert len(cache) == 2
    again = _scripted_client(cache, "model-a").call("motion", PROMPT, CONFIG)
    assert again.text == "north" and again.records[0].cached


def test_every_decoding_parameter_and_image_is_part_of_the_key() -> None:
    identity = {"backend": "openai", "model": "m", "base_url": "http://x/v1"}
    base = cache_key(identity, PROMPT, CONFIG)
    changed = [
        replace(CONFIG, temperature=0.7),
        replace(CONFIG, top_p=0.9),
        replace(CONFIG, max_tokens=100),
        replace(CONFIG, seed=1),
        replace(CONFIG, stop=("\n",)),
        replace(CONFIG, json_schema={"type": "object"}),
    ]
    assert all(cache_key(identity, PROMPT, c) != base for c in changed)
    assert cache_key({**identity, "base_url": "http://y/v1"}, PROMPT, CONFIG) != base
    with_image = [Message("user", "Which way?", (ImagePart(b"one"),))]
    other_image = [Message("user", "Which way?", (ImagePart(b"two"),))]
    assert cache_key(identity, with_image, CONFIG) != cache_key(identity, other_image, CONFIG)
    # The timeout cannot change the answer, so it is not part of the key.
    assert cache_key(identity, PROMPT, replace(CONFIG, timeout_s=5.0)) == base


def test_changing_the_temperature_misses(tmp_path: Path) -> None:
    cache = ResponseCache(tmp_path / "cache.sqlite")
    _scripted_client(cache, "m", "first").call("motion", PROMPT, CONFIG)
    warmer = replace(CONFIG, temperature=0.8)
    result = _scripted_client(cache, "m", "second").call("motion", PROMPT, warmer)
    assert result.text == "second" and not result.records[0].cached
    assert len(cache) == 2


def test_replay_with_an_empty_cache_fails_clearly(tmp_path: Path) -> None:
    client = build_client(
        LLMConfig(backend="replay:openai:gpt-4o", cache_path=str(tmp_path / "c.sqlite"))
    )
    with pytest.raises(CacheMissError, match="replay of openai:gpt-4o: no cached answer"):
        client.call("motion", PROMPT, CONFIG)
    with pytest.raises(ValueError, match="set cache_path"):
        LLMConfig(backend="replay:openai:gpt-4o")
    uncached = LLMConfig().model_copy(update={"backend": "replay:openai:gpt-4o"})
    with pytest.raises(ConfigError, match="cache"):  # a copy skips the config's checks
        build_client(uncached)


@pytest.mark.parametrize("system_role", [True, False])
def test_replay_answers_what_the_real_backend_answered(tmp_path: Path, system_role: bool) -> None:
    path = str(tmp_path / "c.sqlite")
    settings = {"cache_path": path, "system_role": system_role}
    with LoopbackOpenAIServer([answer('{"go": "north"}')]) as server:
        live = build_client(LLMConfig(backend="openai:m", base_url=server.base_url, **settings))
        first = live.call("motion", PROMPT, CONFIG)
        replay = build_client(
            LLMConfig(backend="replay:openai:m", base_url=server.base_url, **settings)
        )
        second = replay.call("motion", PROMPT, CONFIG)
        assert len(server.requests) == 1  # the replay never reached the server
        # The other form of the prompt is another request: the replay has no answer for it.
        other = LLMConfig(
            backend="replay:openai:m",
            base_url=server.base_url,
            **settings | {"system_role": not system_role},
        )
        with pytest.raises(CacheMissError):
            build_client(other).call("motion", PROMPT, CONFIG)
    assert second.text == first.text == '{"go": "north"}'
    assert second.records[0].cached and second.records[0].backend == "openai"
    assert second.records[0].prompt_tokens == first.records[0].prompt_tokens


def test_a_corrupt_entry_is_ignored_logged_and_overwritten(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cache = ResponseCache(tmp_path / "cache.sqlite")
    _scripted_client(cache, "m", "good").call("motion", PROMPT, CONFIG)
    with sqlite3.connect(tmp_path / "cache.sqlite") as conn:
        conn.execute("UPDATE responses SET payload = '{broken'")
    with caplog.at_level(logging.WARNING, logger="skyvln_eval.llm.cache"):
        result = _scripted_client(cache, "m", "fresh").call("motion", PROMPT, CONFIG)
    assert result.text == "fresh" and not result.records[0].cached
    assert "corrupt" in caplog.text
    assert _scripted_client(cache, "m").call("motion", PROMPT, CONFIG).text == "fresh"


def test_a_file_that_is_not_a_database_is_moved_aside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "cache.sqlite"
    path.write_bytes(b"this is not sqlite" * 100)
    with caplog.at_level(logging.WARNING, logger="skyvln_eval.llm.cache"):
        cache = ResponseCache(path)
    assert cache.usable and "unusable" in caplog.text
    assert (tmp_path / "cache.sqlite.broken-0").read_bytes().startswith(b"this is not sqlite")
    assert _scripted_client(cache, "m", "ok").call("motion", PROMPT, CONFIG).text == "ok"


def test_backends_have_distinct_identities() -> None:
    rule = create_backend("rule")
    assert rule.identity() == {"backend": "rule", "model": "rule-v1"}
    assert rule.kind == "rule" and "not an LLM" in rule.label
    openai = create_backend("openai:gpt-4o", base_url="http://127.0.0.1:9/v1/")
    assert openai.identity() == {
        "backend": "openai",
        "model": "gpt-4o",
        "base_url": "http://127.0.0.1:9/v1",
    }
    # A pinned structured-output level is another request: an audit saw a run pinned to
    # json_schema served the answers a run pinned to plain prompting had cached.
    pinned = {
        level: create_backend(
            "openai:gpt-4o", base_url="http://127.0.0.1:9/v1/", structured_output=level
        ).identity()
        for level in ("json_schema", "prompt")
    }
    assert pinned["json_schema"] != pinned["prompt"] != openai.identity()
    assert pinned["prompt"] == {**openai.identity(), "structured_output": "prompt"}
    replay = create_backend(
        "replay:openai:gpt-4o", base_url="http://127.0.0.1:9/v1/", structured_output="prompt"
    )
    assert replay.identity() == pinned["prompt"]  # a replay of that run finds its answers
