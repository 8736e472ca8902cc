"""Atomic writes: whole files or nothing, normal permissions."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from skyvln_eval.fileio import atomic_write_bytes, atomic_write_json


def test_written_files_get_normal_permissions(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b.json"
    atomic_write_json(path, {"x": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
    assert path.read_text() == '{"x": 1}\n'
    # MCAP logs too (they were 0600, the temporary file's mode, unlike the rest of a run).
    from skyvln_eval.converters.writer import McapLogWriter

    log = tmp_path / "logs" / "e.mcap"
    with McapLogWriter(log) as writer:
        writer.add_metadata("m", {"k": "v"})
    assert stat.S_IMODE(log.stat().st_mode) == 0o666 & ~mask


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "keep.bin"
    atomic_write_bytes(path, b"old")
    with pytest.raises(TypeError):
        atomic_write_bytes(path, "not bytes")  # type: ignore[arg-type]
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.bin"]


def test_a_durable_write_syncs_its_bytes_and_its_rename(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A run's results, rewritten (a row replaced, damaged rows set aside), are work that a
    # power cut must not lose: the bytes and the folder's entry reach the disk first.
    synced: list[str] = []
    real_fsync = os.fsync

    def recording_fsync(fd: int) -> None:
        synced.append(str(Path(f"/proc/self/fd/{fd}").readlink()))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    atomic_write_bytes(tmp_path / "plain.txt", b"a")
    assert synced == []  # an ordinary write does not wait for the disk
    atomic_write_bytes(tmp_path / "results.jsonl", b"b", durable=True)
    assert len(synced) == 2 and synced[1] == str(tmp_path)
    assert synced[0].startswith(str(tmp_path / ".results.jsonl."))  # the temporary file
    assert (tmp_path / "results.jsonl").read_bytes() == b"b"
