"""The generic log writer: atomic files, declared topics only, time order, determinism."""

from __future__ import annotations

import io
import math
import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader

from skyvln_eval.avdn import Episode, parse_record
from skyvln_eval.converters import McapLogWriter, convert_episode, read_log, read_log_bytes
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.messages import log
from skyvln_eval.errors import ConfigError, McapLogError
from tests.conftest import make_record
from tests.converters.conftest import convert_to_bytes, synthetic_world


def _episode(**overrides: object) -> Episode:
    return Episode("val_seen", "andh", (parse_record(make_record(**overrides)),))


def test_file_appears_only_when_the_block_succeeds(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "ok.mcap"
    with McapLogWriter(path) as writer:
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(0, "commander", "hi"), 0)
        assert not path.exists(), "nothing under the final name while writing"
        assert len(list(path.parent.iterdir())) == 1  # the temporary file
    assert read_log(path).summary().topic_counts == {t.TOPIC_DIALOG_LOG: 1}
    assert [p.name for p in path.parent.iterdir()] == ["ok.mcap"]


def test_an_exception_leaves_no_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    with pytest.raises(RuntimeError), McapLogWriter(path) as writer:
        convert_episode(_episode(), synthetic_world(), writer)
        raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_rewrite_keeps_the_previous_file(tmp_path: Path) -> None:
    path = tmp_path / "e.mcap"
    with McapLogWriter(path) as writer:
        convert_episode(_episode(), None, writer)
    before = path.read_bytes()
    with pytest.raises(KeyboardInterrupt), McapLogWriter(path) as writer:
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(0, "x", "y"), 0)
        raise KeyboardInterrupt
    assert path.read_bytes() == before and len(list(tmp_path.iterdir())) == 1


def test_undeclared_topic_or_wrong_schema_is_refused() -> None:
    with McapLogWriter(io.BytesIO()) as writer:
        with pytest.raises(ConfigError, match="not declared"):
            writer.write("/typo", t.LOG, log(0, "a", "b"), 0)
        with pytest.raises(ConfigError, match="declared with schema"):
            writer.write(t.TOPIC_DIALOG_LOG, t.COMPRESSED_IMAGE, log(0, "a", "b"), 0)


def test_time_must_not_go_back() -> None:
    with McapLogWriter(io.BytesIO()) as writer:
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(5, "a", "b"), 5)
        with pytest.raises(ConfigError, match="goes back in time"):
            writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(4, "a", "b"), 4)
        with pytest.raises(ConfigError, match="non-negative int"):
            writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(5, "a", "b"), 5.0)  # type: ignore[arg-type]


def test_nan_and_unserialisable_messages_are_refused_with_the_topic() -> None:
    with McapLogWriter(io.BytesIO()) as writer:
        with pytest.raises(McapLogError, match="/dialog/log"):
            writer.write(t.TOPIC_DIALOG_LOG, t.LOG, {"x": math.nan}, 0)
        with pytest.raises(McapLogError, match="cannot be encoded"):
            writer.write(t.TOPIC_DIALOG_LOG, t.LOG, {"x": object()}, 0)


def test_metadata_values_must_be_strings() -> None:
    with McapLogWriter(io.BytesIO()) as writer, pytest.raises(ConfigError, match="not strings"):
        writer.add_metadata("m", {"a": 1})  # type: ignore[dict-item]


def test_writing_outside_the_block_is_an_error() -> None:
    writer = McapLogWriter(io.BytesIO())
    with pytest.raises(ConfigError, match="not open"):
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(0, "a", "b"), 0)


def test_conversion_is_byte_identical_and_depends_on_the_input() -> None:
    world = synthetic_world()
    first = convert_to_bytes(_episode(), world)
    assert convert_to_bytes(_episode(), world) == first
    assert convert_to_bytes(_episode(), synthetic_world()) == first  # a fresh, equal world
    assert convert_to_bytes(_episode(heading=31.0), world) != first
    assert b"skyvln-eval" in first[:64]  # fixed library string in the header


def test_files_use_zstd_chunks_indexes_and_crcs(tmp_path: Path) -> None:
    path = tmp_path / "e.mcap"
    path.write_bytes(convert_to_bytes(_episode(), synthetic_world()))
    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.chunk_indexes and all(c.compression == "zstd" for c in summary.chunk_indexes)
    assert all(c.message_index_offsets for c in summary.chunk_indexes)
    assert summary.metadata_indexes and summary.schemas and summary.channels
    data = path.read_bytes()
    (data_crc,) = struct.unpack_from("<I", data, _data_end_offset(data) + 9)
    assert data_crc != 0
    assert read_log_bytes(data).messages


def _data_end_offset(data: bytes) -> int:
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    return int(summary_start) - 13


def test_metadata_says_what_the_log_holds_without_a_world() -> None:
    # Converted without a world, the log has no map tile and no observation; its metadata
    # claimed the defaults (observations=true, a 384 px tile).
    log_file = read_log_bytes(convert_to_bytes(_episode(), None))
    meta = log_file.metadata[t.EPISODE_METADATA]
    topics = set(log_file.summary().topic_counts)
    assert not topics & {t.TOPIC_MAP_TILE, t.TOPIC_GT_OBSERVATION}
    assert (meta["observations"], meta["map_tile_max_side_px"]) == ("false", "0")
    with_world = read_log_bytes(convert_to_bytes(_episode(), synthetic_world()))
    assert {t.TOPIC_MAP_TILE, t.TOPIC_GT_OBSERVATION} <= set(with_world.summary().topic_counts)
    meta = with_world.metadata[t.EPISODE_METADATA]
    assert (meta["observations"], meta["map_tile_max_side_px"]) == ("true", "384")
