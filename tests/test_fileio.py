"""Atomic writes: whole files or nothing, normal permissions."""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

import pytest

from skyvln_eval.errors import ConfigError
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


def _config_readers() -> list[tuple[str, Callable[[Path], object]]]:
    from skyvln_eval.agent.config import AgentConfig
    from skyvln_eval.control.registry import load_controller
    from skyvln_eval.harness.config import load_run_config
    from skyvln_eval.harness.plan import load_plan
    from skyvln_eval.llm.backends_file import load_backends_file
    from skyvln_eval.llm.prices import load_prices

    return [
        ("run config", load_run_config),
        ("reproduce plan", load_plan),
        ("agent config", AgentConfig.from_yaml),
        ("backends file", load_backends_file),
        ("price table", load_prices),
        ("controller config", load_controller),
    ]


@pytest.mark.parametrize(("what", "read"), [pytest.param(*r, id=r[0]) for r in _config_readers()])
def test_a_broken_yaml_file_is_named_in_the_parsers_own_marks(
    tmp_path: Path, what: str, read: Callable[[Path], object]
) -> None:
    # PyYAML, given the text rather than the file, said: in "<unicode string>", line 2.
    path = tmp_path / "broken.yaml"
    path.write_text("format: x\nagent:\n  name: [unclosed\n")
    with pytest.raises(ConfigError) as caught:
        read(path)
    assert f'in "{path}", line 3' in str(caught.value), what
    assert "<unicode string>" not in str(caught.value)
