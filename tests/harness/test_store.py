"""The result store keeps whole rows only, drops a partial last line, and resumes exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.avdn import view_from_pose
from skyvln_eval.errors import FormatVersionError
from skyvln_eval.harness.store import RESULTS_FILE, ResultStore
from skyvln_eval.metrics import EpisodeResult, read_results

VIEW = view_from_pose((30.005, 40.005), 0.0, 100.0)


def result(i: int, status: str = "ok") -> EpisodeResult:
    return EpisodeResult(
        episode_id=f"9101__{i}_1",
        split="val_seen",
        mode="andh",
        system="test",
        status=status,  # type: ignore[arg-type]
        visited_views=np.stack([VIEW, VIEW + 1e-4 * i]),
        gt_path_corners=np.stack([VIEW, VIEW]),
        error=None if status == "ok" else "RuntimeError: boom",
    )


def test_rows_survive_reopening_and_are_a_results_file(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    for i in (2, 0, 1):  # in the order they finished
        store.append(result(i))
    again = ResultStore(tmp_path)
    # Handed back by key, whatever order the workers finished in.
    assert [r.episode_id for r in again.results()] == ["9101__0_1", "9101__1_1", "9101__2_1"]
    assert [r.episode_id for r in store.results()] == ["9101__0_1", "9101__1_1", "9101__2_1"]
    assert again.results()[1] == result(1)
    assert again.recovery.messages() == []
    assert read_results(tmp_path / RESULTS_FILE) == [result(i) for i in (2, 0, 1)]


def test_a_partial_last_line_is_dropped_and_reported(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    store.append(result(0))
    store.append(result(1))
    path = tmp_path / RESULTS_FILE
    whole = path.read_bytes()
    path.write_bytes(whole + b'{"episode_id": "9101__2_1", "spl')  # killed mid-write
    again = ResultStore(tmp_path)
    assert len(again) == 2
    assert again.recovery.dropped_partial_bytes == len(b'{"episode_id": "9101__2_1", "spl')
    assert "incomplete last row" in again.recovery.messages()[0]
    assert path.read_bytes() == whole  # truncated back to whole rows
    keys = [("val_seen", f"9101__{i}_1") for i in range(4)]
    assert again.missing(keys) == keys[2:]
    again.append(result(2))
    assert [r.episode_id for r in ResultStore(tmp_path).results()] == [k[1] for k in keys[:3]]


def test_failed_rows_count_as_done_unless_retried_and_are_compacted(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    store.append(result(0, "error"))
    key = ("val_seen", "9101__0_1")
    assert store.missing([key]) == []
    assert store.missing([key], retry_failed=True) == [key]
    store.append(result(0))
    again = ResultStore(tmp_path)
    assert again.get(key).status == "ok"  # type: ignore[union-attr]
    assert again.recovery.superseded == [key]
    assert len(read_results(tmp_path / RESULTS_FILE)) == 1  # compacted: no duplicate left


def test_files_from_another_format_version_are_refused(tmp_path: Path) -> None:
    (tmp_path / RESULTS_FILE).write_text(
        json.dumps({"format": "skyvln-eval.episode-results", "version": 99}) + "\n"
    )
    with pytest.raises(FormatVersionError, match="another version"):
        ResultStore(tmp_path)
