"""The response cache created and used by many threads and processes at the same moment:
nothing moved aside, no answer lost; a cache is moved aside only when really corrupt."""

from __future__ import annotations

import multiprocessing
import sqlite3
import threading
from pathlib import Path
from typing import Any

from skyvln_eval.llm import ResponseCache
from skyvln_eval.llm.types import Completion


def _create_and_put(path: Path, name: str, barrier: Any) -> None:
    barrier.wait()  # everyone opens the (missing) cache at once
    cache = ResponseCache(path)
    cache.put(f"key-{name}", Completion(text=name, backend="scripted", model="m"))
    cache.close()


def _answers(path: Path) -> set[str]:
    cache = ResponseCache(path)
    try:
        found = {cache.get(f"key-{n}") for n in _names(path)}
        return {c.text for c in found if c is not None}
    finally:
        cache.close()


def _names(path: Path) -> list[str]:
    with sqlite3.connect(path) as conn:
        return [k.removeprefix("key-") for (k,) in conn.execute("SELECT key FROM responses")]


def test_many_threads_creating_one_cache_at_once_lose_nothing(tmp_path: Path) -> None:
    # Before the fix, 24 threads creating the same cache moved it aside in about one trial
    # of five (UNIQUE constraint failed: meta.key), losing every answer written meanwhile.
    threads_per_trial = 24
    for trial in range(40):
        path = tmp_path / f"trial-{trial}" / "cache.sqlite"
        barrier = threading.Barrier(threads_per_trial)
        names = [f"t{i}" for i in range(threads_per_trial)]
        threads = [
            threading.Thread(target=_create_and_put, args=(path, name, barrier)) for name in names
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert not list(path.parent.glob("*.broken-*")), f"trial {trial}: a sound cache moved"
        assert _answers(path) == set(names), f"trial {trial}: answers lost"


def test_processes_and_threads_creating_one_cache_at_once_lose_nothing(tmp_path: Path) -> None:
    context = multiprocessing.get_context("spawn")
    path = tmp_path / "cache.sqlite"
    barrier = context.Barrier(4 + 8)
    processes = [
        context.Process(target=_create_and_put, args=(path, f"p{i}", barrier)) for i in range(4)
    ]
    threads = [
        threading.Thread(target=_create_and_put, args=(path, f"t{i}", barrier)) for i in range(8)
    ]
    for process in processes:
        process.start()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for process in processes:
        process.join(timeout=120)
        assert process.exitcode == 0
    assert not list(tmp_path.glob("*.broken-*"))
    assert _answers(path) == {f"p{i}" for i in range(4)} | {f"t{i}" for i in range(8)}


def test_a_busy_cache_is_waited_for_not_moved_aside(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    ResponseCache(path).put("key-first", Completion(text="first", backend="b", model="m"))
    holder = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    holder.execute("BEGIN EXCLUSIVE")  # another process in the middle of a long write
    release = threading.Timer(0.5, lambda: holder.execute("COMMIT"))
    release.start()
    try:
        cache = ResponseCache(path)
        assert cache.usable
        cache.put("key-second", Completion(text="second", backend="b", model="m"))
    finally:
        release.join()
        holder.close()
    assert not list(tmp_path.glob("*.broken-*"))
    assert _answers(path) == {"first", "second"}


def test_a_corrupt_cache_is_moved_aside_and_a_new_one_started(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    path.write_bytes(b"SQLite format 3\x00" + b"\xff" * 4000)  # a header, then garbage
    cache = ResponseCache(path)
    assert cache.usable
    cache.put("key-new", Completion(text="new", backend="b", model="m"))
    assert (tmp_path / "cache.sqlite.broken-0").read_bytes().startswith(b"SQLite format 3")
    assert _answers(path) == {"new"}


def test_a_cache_of_another_version_is_moved_aside(tmp_path: Path) -> None:
    path = tmp_path / "cache.sqlite"
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT)")
        old = [("format", "skyvln-eval/llm-cache"), ("version", "1")]
        conn.executemany("INSERT INTO meta VALUES (?, ?)", old)
    cache = ResponseCache(path)
    assert cache.usable and len(cache) == 0
    assert (tmp_path / "cache.sqlite.broken-0").is_file()
