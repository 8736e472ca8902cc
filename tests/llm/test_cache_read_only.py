"""A cache that cannot be written is read (answers served, new ones not stored), and a
replay refuses one it cannot read at all, saying why, rather than missing on every call.

File modes make a cache unwritable for an ordinary user, not for root (these tests run as
both): as root the writable opening is made to fail as SQLite fails it on a read-only
file system, and the read-only opening that follows is the real one.
"""

from __future__ import annotations

import logging
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.errors import ConfigError
from skyvln_eval.llm import (
    GenerationConfig,
    LLMClient,
    LLMConfig,
    Message,
    ResponseCache,
    build_client,
)
from skyvln_eval.llm import cache as cache_module
from skyvln_eval.llm.simple import ScriptedBackend

PROMPT = [Message("user", "Which way?")]
OTHER = [Message("user", "And then?")]
CONFIG = GenerationConfig(timeout_s=2.0)
LOGGER = "skyvln_eval.llm.cache"


def _client(cache: ResponseCache, *answers: str) -> LLMClient:
    return LLMClient(ScriptedBackend(list(answers), model="m"), cache=cache)


def _written(path: Path) -> Path:
    """A closed cache at ``path`` holding one answer ("north") to ``PROMPT``."""
    cache = ResponseCache(path)
    assert _client(cache, "north").call("motion", PROMPT, CONFIG).text == "north"
    cache.close()
    return path


def _refuse_writing(monkeypatch: pytest.MonkeyPatch) -> None:
    """The writable opening fails as on a read-only file system."""

    def unwritable(self: ResponseCache) -> sqlite3.Connection:
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(ResponseCache, "_open", unwritable)


@pytest.fixture
def read_only_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A cache with one answer that this process cannot write."""
    folder = tmp_path / "ro"
    path = _written(folder / "cache.sqlite")
    if os.geteuid() == 0:  # root writes whatever the modes say
        _refuse_writing(monkeypatch)
        yield path
        return
    path.chmod(0o444)
    folder.chmod(0o555)
    try:
        yield path
    finally:
        folder.chmod(0o755)
        path.chmod(0o644)


def test_a_read_only_cache_serves_its_answers_and_stores_none(
    read_only_cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        cache = ResponseCache(read_only_cache)
        hit = _client(cache, "south").call("motion", PROMPT, CONFIG)
        fresh = _client(cache, "west").call("motion", OTHER, CONFIG)
        again = ResponseCache(read_only_cache)  # the next episode's client
    assert cache.usable and cache.read_only and cache.problem
    assert hit.text == "north" and hit.records[0].cached  # not asked again
    assert fresh.text == "west" and not fresh.records[0].cached
    assert len(cache) == 1  # the new answer was not stored, and no write was tried:
    assert "write failed" not in caplog.text
    said = [r.getMessage() for r in caplog.records if "read-only" in r.getMessage()]
    assert len(said) == 1, said  # said once, not once per client
    assert "new ones are not stored" in said[0] and "caching is off" not in caplog.text
    assert again.read_only and again.get(next(iter(_keys(read_only_cache)))) is not None
    cache.close()
    again.close()


def _keys(path: Path) -> list[str]:
    with sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro&immutable=1", uri=True) as conn:
        return [key for (key,) in conn.execute("SELECT key FROM responses")]


def test_replay_answers_from_a_read_only_cache(read_only_cache: Path) -> None:
    # Before, the replay found the cache "off" and blamed every call on its contents.
    client = build_client(LLMConfig(backend="replay:scripted:m", cache_path=str(read_only_cache)))
    replayed = client.call("motion", PROMPT, CONFIG)
    assert replayed.text == "north" and replayed.records[0].cached
    assert client.cache is not None and client.cache.read_only
    client.cache.close()


def test_a_wal_cache_whose_index_cannot_be_made_is_read_as_immutable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """In a read-only folder SQLite cannot make a WAL database's ``-shm`` index, so plain
    ``mode=ro`` fails (as in the audit's read-only mount); ``immutable`` reads it."""
    path = _written(tmp_path / "cache.sqlite")
    _refuse_writing(monkeypatch)
    connect = sqlite3.connect
    tried: list[str] = []

    def no_index(target: Any, *args: Any, **kwargs: Any) -> sqlite3.Connection:
        tried.append(str(target))
        if "immutable=1" not in str(target):
            raise sqlite3.OperationalError("unable to open database file")
        return connect(target, *args, **kwargs)

    monkeypatch.setattr(cache_module.sqlite3, "connect", no_index)
    cache = ResponseCache(path)
    assert cache.read_only and len(cache) == 1
    assert [t.rsplit("?", 1)[-1] for t in tried] == ["mode=ro", "mode=ro&immutable=1"]
    cache.close()
    # A -wal file may hold answers the main file lacks: not read as immutable then.
    path.with_name(path.name + "-wal").write_bytes(b"")
    unread = ResponseCache(path)
    assert not unread.usable and "read-only too" in (unread.problem or "")


def test_replay_refuses_a_cache_it_cannot_open_saying_why(tmp_path: Path) -> None:
    folder = tmp_path / "a-folder-not-a-file"
    folder.mkdir()
    with pytest.raises(ConfigError, match=r"cannot be opened \(unable to open database file"):
        build_client(LLMConfig(backend="replay:openai:m", cache_path=str(folder)))
    # An ordinary backend runs without it, as before.
    assert build_client(LLMConfig(backend="rule", cache_path=str(folder))).cache is not None


def test_a_cache_that_cannot_be_opened_is_said_once_not_once_per_client(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # A run builds a client per episode: "caching is off" was logged for every episode.
    folder = tmp_path / "a-folder-not-a-file"
    folder.mkdir()
    with caplog.at_level(logging.ERROR, logger=LOGGER):
        caches = [ResponseCache(folder) for _ in range(3)]
    assert not any(cache.usable for cache in caches)
    assert sum("caching is off" in r.getMessage() for r in caplog.records) == 1
