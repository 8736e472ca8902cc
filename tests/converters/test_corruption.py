"""Damaged files give a clear error naming the file, never a crash or a partial read."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyvln_eval.avdn import Episode, parse_record
from skyvln_eval.converters import McapLogWriter, read_episode, read_episode_bytes
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.convert import DEFAULT_OPTIONS, episode_metadata
from skyvln_eval.converters.messages import log
from skyvln_eval.converters.reader import LogMessage, read_log_bytes
from skyvln_eval.converters.validate import check_log_bytes
from skyvln_eval.errors import FormatVersionError, McapLogError
from tests.conftest import make_record
from tests.converters.conftest import chunk_payload_span, convert_to_bytes, synthetic_world

EPISODE = Episode("val_seen", "andh", (parse_record(make_record(n_views=4)),))
GOOD = convert_to_bytes(EPISODE, synthetic_world())


def _write(tmp_path: Path, data: bytes, name: str = "e.mcap") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def test_the_good_file_reads(tmp_path: Path) -> None:
    assert read_episode(_write(tmp_path, GOOD)) == EPISODE


@pytest.mark.parametrize("keep", [0.25, 0.5, 0.9, 0.999])
def test_truncated_file(tmp_path: Path, keep: float) -> None:
    path = _write(tmp_path, GOOD[: int(len(GOOD) * keep)])
    with pytest.raises(McapLogError, match="truncated") as info:
        read_episode(path)
    assert str(path) in str(info.value)


def test_empty_file(tmp_path: Path) -> None:
    with pytest.raises(McapLogError, match="an empty file, not an MCAP log"):
        read_episode(_write(tmp_path, b""))


@pytest.mark.parametrize("where", [0.0, 0.3, 0.6, 0.99])
def test_flipped_byte_in_a_chunk(tmp_path: Path, where: float) -> None:
    start, end = chunk_payload_span(GOOD)
    damaged = bytearray(GOOD)
    damaged[start + int((end - start - 1) * where)] ^= 0x40
    path = _write(tmp_path, bytes(damaged))
    with pytest.raises(McapLogError, match="damaged MCAP file") as info:
        read_episode(path)
    assert str(path) in str(info.value)


def test_flipped_chunk_byte_is_caught_by_the_chunk_crc_too() -> None:
    """Even without the data-section CRC, the chunk's own CRC or zstd catches the change."""
    from skyvln_eval.converters.reader import _records

    start, end = chunk_payload_span(GOOD)
    damaged = bytearray(GOOD)
    damaged[(start + end) // 2] ^= 0x01
    with pytest.raises(McapLogError, match="damaged"):
        _records(bytes(damaged), "x.mcap")


@settings(max_examples=300, deadline=None)
@given(position=st.integers(0, len(GOOD) - 1), mask=st.integers(1, 255))
def test_any_flipped_byte_is_an_error_never_a_crash(position: int, mask: int) -> None:
    damaged = bytearray(GOOD)
    damaged[position] ^= mask
    # Every byte is covered by a CRC (data section, summary) or is the magic itself.
    with pytest.raises(McapLogError, match=r"damaged\.mcap"):
        read_episode_bytes(bytes(damaged), "damaged.mcap")


def _with_episode_metadata(**changes: str) -> bytes:
    import io

    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        writer.add_metadata(
            t.EPISODE_METADATA, {**episode_metadata(EPISODE, DEFAULT_OPTIONS), **changes}
        )
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(0, "a", "b"), 0)
    return buffer.getvalue()


def test_wrong_format_version(tmp_path: Path) -> None:
    path = _write(tmp_path, _with_episode_metadata(format_version="2"))
    with pytest.raises(FormatVersionError, match="upgrade skyvln-eval") as info:
        read_episode(path)
    assert str(path) in str(info.value) and "'2'" in str(info.value)
    with pytest.raises(FormatVersionError, match="skyvln-eval convert") as old:
        read_episode(_write(tmp_path, _with_episode_metadata(format_version="0"), "old.mcap"))
    assert "a run's logs by running it again into a new run directory" in str(old.value)


def test_own_schema_version_is_checked(tmp_path: Path) -> None:
    import io

    from mcap.writer import Writer

    buffer = io.BytesIO()
    writer = Writer(buffer, enable_data_crcs=True)
    writer.start(t.MCAP_PROFILE, t.MCAP_LIBRARY)
    writer.add_metadata(t.EPISODE_METADATA, episode_metadata(EPISODE, DEFAULT_OPTIONS))
    schema = writer.register_schema(t.DIALOG_TURN, t.SCHEMA_ENCODING, t.schema_bytes(t.DIALOG_TURN))
    channel = writer.register_channel(t.TOPIC_DIALOG, "json", schema, {t.SCHEMA_VERSION_KEY: "99"})
    writer.add_message(channel, 0, b"{}", 0)
    writer.finish()
    with pytest.raises(FormatVersionError, match=r"skyvln_eval\.DialogTurn 99"):
        read_episode(_write(tmp_path, buffer.getvalue()))


def test_not_an_mcap_file(tmp_path: Path) -> None:
    path = _write(tmp_path, b'[{"map_name": "1913"}]\n', "records.mcap")
    with pytest.raises(McapLogError, match="not an MCAP file") as info:
        read_episode(path)
    assert str(path) in str(info.value)


def test_a_log_that_is_not_an_episode_log(tmp_path: Path) -> None:
    import io

    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        writer.write(t.TOPIC_DIALOG_LOG, t.LOG, log(0, "a", "b"), 0)
    with pytest.raises(McapLogError, match="not an episode log"):
        read_episode(_write(tmp_path, buffer.getvalue()))


def test_missing_file_and_folder(tmp_path: Path) -> None:
    with pytest.raises(McapLogError, match="file not found"):
        read_episode(tmp_path / "nope.mcap")
    with pytest.raises(McapLogError, match="is a folder"):
        read_episode(tmp_path)


def _rewritten(edit: Callable[[LogMessage], bytes | None]) -> bytes:
    """GOOD written again (valid framing, CRCs, schemas) with ``edit`` applied to each
    message: the new bytes, or None to leave the message out."""
    import io

    log = read_log_bytes(GOOD, "good.mcap")
    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        for name, values in log.metadata.items():
            writer.add_metadata(name, values)
        for message in log.messages:
            data = edit(message)
            if data is not None:
                writer.write(message.topic, message.schema_name, data, message.log_time_ns)
    return buffer.getvalue()


def test_validate_finds_messages_that_differ_from_the_records() -> None:
    # The metadata's records are what replays and scores read; a log whose messages were
    # edited after conversion (here the commander's words) showed another episode in a viewer.
    assert check_log_bytes(GOOD).issues == ()
    assert check_log_bytes(_rewritten(lambda m: m.data)).issues == ()

    def other_words(message: LogMessage) -> bytes:
        if message.topic != t.TOPIC_DIALOG:
            return message.data
        return message.data.replace(b'"text":"', b'"text":"Turn back. ')

    (issue,) = check_log_bytes(_rewritten(other_words), "edited.mcap").issues
    assert issue.field == t.TOPIC_DIALOG and "not what the episode's records make" in issue.message
    assert issue.episode_id == EPISODE.episode_id


def test_validate_counts_the_images_a_log_says_it_holds() -> None:
    first_view = True

    def drop_first_observation(message: LogMessage) -> bytes | None:
        nonlocal first_view
        if message.topic == t.TOPIC_GT_OBSERVATION and first_view:
            first_view = False
            return None
        return message.data

    (issue,) = check_log_bytes(_rewritten(drop_first_observation)).issues
    assert issue.field == t.TOPIC_GT_OBSERVATION
    assert issue.message.startswith("3 message(s), its metadata says 4")
