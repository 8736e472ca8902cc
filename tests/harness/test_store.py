"""The result store keeps whole rows only, sets damaged lines aside with their line numbers,
survives a full disk, and resumes exactly."""

from __future__ import annotations

import dataclasses
import errno
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skyvln_eval.avdn import view_from_pose
from skyvln_eval.errors import FormatVersionError, ResultsWriteError
from skyvln_eval.harness.store import DAMAGED_FILE, RESULTS_FILE, ResultStore
from skyvln_eval.metrics import EpisodeResult, read_results
from skyvln_eval.metrics.results_io import result_to_json_dict

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
    # Replaced at once: `score` reads the file between two runs and refuses duplicates.
    assert [r.status for r in read_results(tmp_path / RESULTS_FILE)] == ["ok"]
    again = ResultStore(tmp_path)
    assert again.get(key).status == "ok"  # type: ignore[union-attr]
    # A file holding two rows of one episode all the same is compacted on opening.
    path = tmp_path / RESULTS_FILE
    error_row = json.dumps(result_to_json_dict(result(0, "error"))).encode() + b"\n"
    ok_row = path.read_bytes().split(b"\n")[1] + b"\n"
    path.write_bytes(path.read_bytes() + error_row + ok_row)
    compacted = ResultStore(tmp_path)
    assert compacted.recovery.superseded == [key, key]
    assert [r.status for r in read_results(path)] == ["ok"]


def test_files_from_another_format_version_are_refused(tmp_path: Path) -> None:
    (tmp_path / RESULTS_FILE).write_text(
        json.dumps({"format": "skyvln-eval.episode-results", "version": 99}) + "\n"
    )
    with pytest.raises(FormatVersionError, match="another version"):
        ResultStore(tmp_path)


def _damaged_file(tmp_path: Path, n: int = 4) -> tuple[Path, list[bytes]]:
    store = ResultStore(tmp_path)
    for i in range(n):
        store.append(result(i))
    path = tmp_path / RESULTS_FILE
    return path, path.read_bytes().split(b"\n")


def _side_rows(tmp_path: Path) -> list[dict[str, object]]:
    lines = (tmp_path / DAMAGED_FILE).read_text().splitlines()
    header = json.loads(lines[0])
    assert header["format"] == "skyvln-eval.damaged-result-rows" and header["version"] == 1
    return [json.loads(line) for line in lines[1:]]


def test_a_damaged_middle_row_is_set_aside_and_its_episode_runs_again(tmp_path: Path) -> None:
    path, lines = _damaged_file(tmp_path)
    lines[2] = lines[2][:70] + b"\x00\x00 garbage"  # line 3 of the file: episode 1
    path.write_bytes(b"\n".join(lines))
    again = ResultStore(tmp_path)
    assert len(again) == 3
    keys = [("val_seen", f"9101__{i}_1") for i in range(4)]
    assert again.missing(keys) == [keys[1]]
    [message] = again.recovery.messages()
    assert message.startswith("results.jsonl line 3: damaged row (not JSON")
    assert f"set aside in {tmp_path / DAMAGED_FILE}" in message
    assert message.endswith("episode val_seen/9101__1_1 runs again")
    [aside] = _side_rows(tmp_path)
    assert aside["line"] == 3 and aside["episode"] == "val_seen/9101__1_1"
    text = str(aside["text"])
    assert text.startswith('{"episode_id":"9101__1_1"') and "\x00" in text
    # The file now holds whole rows only, and reads as a results file.
    assert [r.episode_id for r in read_results(path)] == ["9101__0_1", "9101__2_1", "9101__3_1"]


def test_a_damaged_last_row_ending_with_a_newline_is_set_aside(tmp_path: Path) -> None:
    path, lines = _damaged_file(tmp_path)
    lines[4] = lines[4][: len(lines[4]) // 2]  # the last row cut, yet its line ends
    path.write_bytes(b"\n".join(lines))
    assert path.read_bytes().endswith(b"\n")
    again = ResultStore(tmp_path)
    assert len(again) == 3
    assert again.recovery.messages()[0].startswith("results.jsonl line 5: damaged row (not JSON")
    assert [row["line"] for row in _side_rows(tmp_path)] == [5]


def test_a_side_file_cut_mid_append_keeps_the_next_rows_whole(tmp_path: Path) -> None:
    """Killed while setting rows aside, the side file ended in half a line: the next rows
    set aside were appended to it, and the first of them was lost in that line."""
    path, lines = _damaged_file(tmp_path)
    path.write_bytes(b"\n".join([*lines[:2], b"garbage one", *lines[2:]]))
    ResultStore(tmp_path)
    side = tmp_path / DAMAGED_FILE
    side.write_bytes(side.read_bytes()[:-15])  # the kill
    path.write_bytes(path.read_bytes() + b"garbage two\n")
    ResultStore(tmp_path)
    last = side.read_bytes().split(b"\n")[-2]
    assert json.loads(last)["text"] == "garbage two"


def test_rows_that_are_json_but_not_rows_and_a_damaged_header(tmp_path: Path) -> None:
    path, lines = _damaged_file(tmp_path)
    row = json.loads(lines[2])
    row["status"] = 7
    del row["visited_views"]
    lines[0] = b'{"format": "skyvln-eval.episode-res'  # the header line damaged too
    lines[2] = json.dumps(row).encode()
    lines[3] = b"[1, 2, 3]"
    path.write_bytes(b"\n".join(lines))
    again = ResultStore(tmp_path)
    assert sorted(r.episode_id for r in again.results()) == ["9101__0_1", "9101__3_1"]
    reasons = {d.line: d.reason for d in again.recovery.damaged}
    assert reasons[1] == "damaged header line"
    assert reasons[3] == "not a valid row: visited_views: missing required key(s) ['visited_views']"
    assert reasons[4].startswith("not a valid row") and "JSON object" in reasons[4]
    assert read_results(path)[0].episode_id == "9101__0_1"  # a good header again


def test_a_tail_of_zero_bytes_left_by_a_power_cut_is_set_aside(tmp_path: Path) -> None:
    path, _ = _damaged_file(tmp_path, 2)
    path.write_bytes(path.read_bytes() + b"\x00" * 4096)  # no line end: an unfinished block
    again = ResultStore(tmp_path)
    assert len(again) == 2 and again.recovery.dropped_partial_bytes == 4096
    assert "incomplete last row" in again.recovery.messages()[0]
    assert not path.read_bytes().endswith(b"\x00")


def test_opened_to_read_only_the_file_is_left_as_it_is(tmp_path: Path) -> None:
    path, lines = _damaged_file(tmp_path, 3)
    lines[2] = b"{broken"
    damaged = b"\n".join(lines) + b'{"episode_id": "9101__9'
    path.write_bytes(damaged)
    reader = ResultStore(tmp_path, repair=False)
    assert len(reader) == 2 and len(reader.recovery.damaged) == 2
    assert "skipped (the file is left as it is)" in reader.recovery.messages()[0]
    assert path.read_bytes() == damaged and not (tmp_path / DAMAGED_FILE).exists()


class _FullDisk(io.BufferedWriter):
    """A file on a disk with ``room`` bytes left: the write that overflows fails with
    ENOSPC after writing what fitted, as the kernel does."""

    room = 0

    def write(self, data: Any) -> int:
        if len(data) > _FullDisk.room:
            super().write(bytes(data)[: _FullDisk.room])
            super().flush()
            _FullDisk.room = 0
            raise OSError(errno.ENOSPC, "No space left on device", str(self.name))
        _FullDisk.room -= len(data)
        return super().write(data)


def test_a_full_disk_while_appending_keeps_every_completed_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path, _ = _damaged_file(tmp_path, 3)
    before = path.read_bytes()
    real_open = Path.open

    def full_open(self: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        if mode == "ab":
            return _FullDisk(io.FileIO(self, "ab"))
        return real_open(self, mode, *args, **kwargs)

    store = ResultStore(tmp_path)
    _FullDisk.room = 100  # part of the next row fits
    monkeypatch.setattr(Path, "open", full_open)
    with pytest.raises(ResultsWriteError) as full:
        store.append(result(3))
    monkeypatch.undo()
    message = str(full.value)
    assert message.startswith(f"cannot record episode val_seen/9101__3_1 in {path}: ")
    assert "No space left on device (ENOSPC)" in message and "is full" in message
    assert "The 3 row(s) recorded before it are intact" in message
    assert path.read_bytes() == before  # the partial row was taken back off
    again = ResultStore(tmp_path)
    assert len(again) == 3 and again.recovery.messages() == []
    keys = [("val_seen", f"9101__{i}_1") for i in range(4)]
    assert again.missing(keys) == [keys[3]]


def test_a_row_that_stopped_the_run_does_not_count_as_done(tmp_path: Path) -> None:
    store = ResultStore(tmp_path)
    stopped = dataclasses.replace(result(0, "error"), extra={"fatal": "credentials refused"})
    store.append(stopped)
    key = ("val_seen", "9101__0_1")
    assert ResultStore(tmp_path).missing([key]) == [key]
    store.append(result(0))
    assert ResultStore(tmp_path).missing([key]) == []
