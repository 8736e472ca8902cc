"""A run's response cache: a relative ``cache_path`` is inside the run's ``--out`` (as a
plan's is inside its ``--out``), the config keeps it as written, and a cache that cannot
be used is said before any episode runs (a replay's refused)."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from skyvln_eval.errors import ConfigError
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.run import CONFIG_FILE, REPORT_FILE
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.llm import ResponseCache
from skyvln_eval.metrics import read_results

MakeConfig = Callable[..., RunConfig]


def _with_cache(small_config: MakeConfig, cache_path: str, backend: str = "rule") -> RunConfig:
    agent: dict[str, Any] = {
        "name": "skyvln",
        "llm": {"backend": backend, "cache_path": cache_path},
    }
    return small_config(limit=1, agent=agent)


def test_a_relative_cache_path_is_inside_the_run_directory(
    small_config: MakeConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    elsewhere = tmp_path / "working-directory"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    config = _with_cache(small_config, "llm-cache.sqlite")
    run_dir = Path("runs") / "ok"  # relative, as `run ... --out runs/ok`
    first = run(config, run_dir)
    assert first.complete
    # Before, the cache was ./llm-cache.sqlite, wherever the command was started.
    assert not (elsewhere / "llm-cache.sqlite").exists()
    assert len(ResponseCache(elsewhere / run_dir / "llm-cache.sqlite")) > 0
    # The config keeps the path as written: the run's identity is where it is not.
    written = yaml.safe_load((run_dir / CONFIG_FILE).read_text())
    assert written["agent"]["llm"]["cache_path"] == "llm-cache.sqlite"
    # Run again (its row's files are lost): it resumes, and reads the answers from there.
    (run_dir / RESULTS_FILE).unlink()
    again = run(config, run_dir)
    assert again.complete
    (row,) = read_results(run_dir / RESULTS_FILE)
    assert row.llm_calls and all(call.cached for call in row.llm_calls)


def test_a_replay_whose_cache_cannot_be_opened_is_refused_before_any_episode(
    small_config: MakeConfig, tmp_path: Path
) -> None:
    folder = tmp_path / "not-a-cache"
    folder.mkdir()  # a folder where the cache file should be: no SQLite can open it
    config = _with_cache(small_config, str(folder), backend="replay:rule")
    with pytest.raises(ConfigError, match=r"replay:rule answers only from its response cache"):
        run(config, tmp_path / "run")
    assert not (tmp_path / "run" / RESULTS_FILE).exists()


def test_a_read_only_cache_is_read_and_the_run_says_nothing_is_stored(
    small_config: MakeConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "shared" / "llm-cache.sqlite"
    config = _with_cache(small_config, str(cache))
    assert run(config, tmp_path / "first").complete
    stored = len(ResponseCache(cache))

    def unwritable(self: ResponseCache) -> sqlite3.Connection:
        # As on a read-only file system (root, which runs these tests, ignores file modes).
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(ResponseCache, "_open", unwritable)
    report = run(config, tmp_path / "second")
    notes = json.loads((tmp_path / "second" / REPORT_FILE).read_text())["notes"]
    assert any("cannot be written" in n and "new answers are not stored" in n for n in notes)
    (row,) = read_results(tmp_path / "second" / RESULTS_FILE)
    assert report.complete and row.llm_calls and all(call.cached for call in row.llm_calls)
    monkeypatch.undo()
    assert len(ResponseCache(cache)) == stored
