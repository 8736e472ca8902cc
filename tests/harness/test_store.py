"""The result store keeps whole rows only, drops a partial last line, and resumes exactly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from skyvln_eval.errors import FormatVersionError
from skyvln_eval.harness.store import RESULTS_FILE, ResultStore, StoredRow


def row(i: int, status: str = "ok") -> StoredRow:
    return StoredRow(
        "val_seen",
        f"9101__{i}_1",
        status,
        {"value": i} if status == "ok" else None,  # type: ignore[arg-type]
        None if status == "ok" else {"type": "RuntimeError", "message": "boom", "traceback": "..."},
    )


def test_rows_survive_reopening(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    for i in range(3):
        store.append(row(i))
    again = ResultStore(tmp_path)
    assert [r.episode_id for r in again.rows()] == ["9101__0_1", "9101__1_1", "9101__2_1"]
    assert again.rows()[1].result == {"value": 1}
    assert again.recovery.messages() == []


def test_a_partial_last_line_is_dropped_and_reported(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    store.append(row(0))
    store.append(row(1))
    path = tmp_path / RESULTS_FILE
    whole = path.read_bytes()
    path.write_bytes(whole + json.dumps(row(2).to_json()).encode()[:25])  # killed mid-write
    again = ResultStore(tmp_path)
    assert len(again) == 2
    assert again.recovery.dropped_partial_bytes == 25
    assert "incomplete last row" in again.recovery.messages()[0]
    assert path.read_bytes() == whole  # truncated back to whole rows
    keys = [("val_seen", f"9101__{i}_1") for i in range(4)]
    assert again.missing(keys) == keys[2:]
    again.append(row(2))
    assert [r.episode_id for r in ResultStore(tmp_path).rows()] == [k[1] for k in keys[:3]]


def test_failed_rows_count_as_done_unless_retried(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    store.append(row(0, "failed"))
    key = ("val_seen", "9101__0_1")
    assert store.missing([key]) == []
    assert store.missing([key], retry_failed=True) == [key]
    store.append(row(0))
    again = ResultStore(tmp_path)
    assert again.get(key).status == "ok"  # type: ignore[union-attr]
    assert again.recovery.superseded == [key]


def test_rows_from_another_format_version_are_refused(tmp_path: Path) -> None:
    data = row(0).to_json() | {"version": 99}
    (tmp_path / RESULTS_FILE).write_text(json.dumps(data) + "\n")
    with pytest.raises(FormatVersionError, match=r"results\.jsonl:1"):
        ResultStore(tmp_path)
