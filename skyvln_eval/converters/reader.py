"""Read MCAP logs back, verifying every byte, and rebuild episodes exactly.

:func:`read_log` loads a whole log (episode logs are small) and refuses anything it
cannot fully trust, with a :class:`~skyvln_eval.errors.McapLogError` naming the file:
not an MCAP file, truncated (no end magic or footer), a summary or data-section CRC
mismatch (any flipped byte), a chunk CRC or decompression failure, or message counts that
disagree with the file's own statistics. There is no partial result.

:func:`read_episode` then checks the format version and re-parses the AVDN
records stored in the metadata with :func:`skyvln_eval.avdn.parse_record`, so the
episode equals the one the AVDN reader produced.
"""

from __future__ import annotations

import hashlib
import io
import json
import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Final

import zstandard
from mcap.exceptions import McapError
from mcap.records import Channel, DataEnd, Header, Message, Metadata, Schema, Statistics
from mcap.stream_reader import CRCValidationError, StreamReader

from skyvln_eval.avdn import EPISODE_MODES, Episode, parse_record
from skyvln_eval.converters import topics
from skyvln_eval.errors import FormatVersionError, McapLogError

MAGIC: Final = b"\x89MCAP0\r\n"
_FOOTER_OPCODE: Final = 0x02
_DATA_END_OPCODE: Final = 0x0F
# opcode (1) + length (8) + summary_start (8) + summary_offset_start (8) + summary_crc (4)
_FOOTER_SIZE: Final = 29
_DATA_END_SIZE: Final = 13  # opcode (1) + length (8) + data_section_crc (4)
#: Errors the mcap and zstandard libraries raise on damaged input.
DECODE_ERRORS: Final = (
    McapError,
    CRCValidationError,
    zstandard.ZstdError,
    struct.error,
    ValueError,
    KeyError,
    IndexError,
    EOFError,
    UnicodeDecodeError,
    OverflowError,
)


@dataclass(frozen=True)
class LogChannel:
    """A channel: topic, schema name and data, and its metadata (own schema versions)."""

    channel_id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    metadata: dict[str, str]


@dataclass(frozen=True)
class LogMessage:
    """One message; ``data`` is its encoded bytes (JSON for the toolkit's logs)."""

    topic: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes

    def decode(self) -> Any:
        return json.loads(self.data)


@dataclass(frozen=True)
class LogSummary:
    """What two independent readers must agree on (see :func:`message_digest`)."""

    topic_counts: dict[str, int]
    start_time_ns: int | None
    end_time_ns: int | None
    metadata: dict[str, dict[str, str]]
    digest: str

    def as_json(self) -> dict[str, Any]:
        return {
            "topic_counts": dict(sorted(self.topic_counts.items())),
            "start_time_ns": None if self.start_time_ns is None else str(self.start_time_ns),
            "end_time_ns": None if self.end_time_ns is None else str(self.end_time_ns),
            "metadata": {k: dict(sorted(v.items())) for k, v in sorted(self.metadata.items())},
            "digest": self.digest,
        }


@dataclass(frozen=True)
class McapLog:
    """A fully verified MCAP log: header strings, channels, messages in file order, metadata."""

    path: str
    profile: str
    library: str
    channels: tuple[LogChannel, ...]
    messages: tuple[LogMessage, ...]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def topic(self, topic: str) -> list[LogMessage]:
        return [m for m in self.messages if m.topic == topic]

    def summary(self) -> LogSummary:
        times = [m.log_time_ns for m in self.messages]
        return LogSummary(
            topic_counts=dict(Counter(m.topic for m in self.messages)),
            start_time_ns=min(times) if times else None,
            end_time_ns=max(times) if times else None,
            metadata=self.metadata,
            digest=message_digest(self.messages),
        )


def message_digest(messages: tuple[LogMessage, ...] | list[LogMessage]) -> str:
    """SHA-256 over every message in sequence order (the writer numbers them from 0).

    For each message: ``f"{topic}\\n{log_time}\\n{publish_time}\\n{sequence}\\n{len(data)}\\n"``
    in UTF-8, then its data. tests/js/read_mcap.mjs computes the same digest.
    """
    digest = hashlib.sha256()
    for m in sorted(messages, key=lambda m: m.sequence):
        head = f"{m.topic}\n{m.log_time_ns}\n{m.publish_time_ns}\n{m.sequence}\n{len(m.data)}\n"
        digest.update(head.encode("utf-8"))
        digest.update(m.data)
    return digest.hexdigest()


def check_ends(head: bytes, tail: bytes, size: int, name: str) -> None:
    """The MCAP magic at both ends of a file of ``size`` bytes (``head`` and ``tail``: its
    first and last 8 bytes), room for a footer between them."""
    if size == 0:
        raise McapLogError(name, "an empty file, not an MCAP log")
    if not head.startswith(MAGIC):
        raise McapLogError(name, f"not an MCAP file (it starts with {head!r}, not the MCAP magic)")
    if size < 2 * len(MAGIC) + _FOOTER_SIZE or tail != MAGIC:
        raise McapLogError(
            name,
            "truncated or unfinished MCAP file (no closing magic): the write was interrupted "
            "or the file was cut; write it again (convert an episode log, resume the run "
            "of a run log) or copy it again",
        )


def check_file_ends(handle: BinaryIO, name: str) -> None:
    """:func:`check_ends` on an open file, read from its ends (a log too large to hold);
    the file is left at its start."""
    size = handle.seek(0, io.SEEK_END)
    handle.seek(max(0, size - len(MAGIC)))
    tail = handle.read(len(MAGIC))
    handle.seek(0)
    head = handle.read(len(MAGIC))
    handle.seek(0)
    check_ends(head, tail, size, name)


def _check_framing(data: bytes, name: str) -> None:
    """Magic at both ends, footer summary CRC, and the data-section CRC."""
    check_file_framing(io.BytesIO(data), name)


def check_file_framing(handle: BinaryIO, name: str) -> None:
    """Magic at both ends, the footer's summary CRC and the data-section CRC of an open
    MCAP file, read in pieces (a log too large to hold); the file is left at its start.
    (The MCAP reader checks each chunk's CRC as it reads it, not these: a changed byte in
    the header, the summary or the footer passed a viewer's reading without a word.)"""
    check_file_ends(handle, name)
    size = handle.seek(0, io.SEEK_END)
    footer_at = size - len(MAGIC) - _FOOTER_SIZE
    handle.seek(footer_at)
    opcode, length, summary_start, offset_start, summary_crc = struct.unpack(
        "<BQQQI", handle.read(_FOOTER_SIZE)
    )
    handle.seek(0)
    if opcode != _FOOTER_OPCODE or length != _FOOTER_SIZE - 9:
        raise McapLogError(name, "damaged MCAP file: no footer record before the closing magic")
    covered_from = summary_start if summary_start else footer_at
    if not (len(MAGIC) <= covered_from <= footer_at) or offset_start > footer_at:
        raise McapLogError(name, "damaged MCAP file: the footer points outside the file")
    if summary_crc and _crc32(handle, covered_from, footer_at + _FOOTER_SIZE - 4) != summary_crc:
        raise McapLogError(name, "damaged MCAP file: summary CRC mismatch (the file was altered)")
    no_data_end = "damaged MCAP file: no data-end record before the summary"
    data_end_at = covered_from - _DATA_END_SIZE
    if data_end_at < len(MAGIC):
        raise McapLogError(name, no_data_end)
    handle.seek(data_end_at)
    data_end = handle.read(_DATA_END_SIZE)
    handle.seek(0)
    if data_end[0] != _DATA_END_OPCODE:
        raise McapLogError(name, no_data_end)
    (data_crc,) = struct.unpack_from("<I", data_end, 9)
    if data_crc and _crc32(handle, 0, data_end_at) != data_crc:
        raise McapLogError(
            name, "damaged MCAP file: data-section CRC mismatch (a byte of the data was changed)"
        )


def _crc32(handle: BinaryIO, start: int, end: int, piece: int = 1 << 20) -> int:
    """CRC-32 of bytes ``start`` to ``end`` of ``handle``, read a piece at a time; the file
    is left at its start."""
    crc = 0
    handle.seek(start)
    left = end - start
    while left > 0:
        block = handle.read(min(piece, left))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    handle.seek(0)
    return crc


def _records(data: bytes, name: str) -> list[Any]:
    try:
        reader = StreamReader(io.BytesIO(data), validate_crcs=True, record_size_limit=len(data))
        return list(reader.records)
    except CRCValidationError as exc:
        raise McapLogError(name, f"damaged MCAP file: {exc}") from exc
    except DECODE_ERRORS as exc:
        raise McapLogError(name, f"damaged MCAP file: {type(exc).__name__}: {exc}") from exc


def read_log_bytes(data: bytes, name: str = "<bytes>") -> McapLog:
    """Verify and decode a whole MCAP log held in memory (see the module docstring)."""
    _check_framing(data, name)
    header: Header | None = None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    raw_messages: list[Message] = []
    metadata: dict[str, dict[str, str]] = {}
    statistics: Statistics | None = None
    for record in _records(data, name):
        if isinstance(record, Header):
            header = record
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            raw_messages.append(record)
        elif isinstance(record, Metadata):
            if record.name in metadata:
                raise McapLogError(name, f"metadata record {record.name!r} appears twice")
            metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Statistics):
            statistics = record
        elif isinstance(record, DataEnd):
            pass
    if header is None:
        raise McapLogError(name, "damaged MCAP file: no header record")
    log_channels = _channels(channels, schemas, name)
    by_id = {c.channel_id: c for c in log_channels}
    messages = []
    for m in raw_messages:
        channel = by_id.get(m.channel_id)
        if channel is None:
            raise McapLogError(name, f"message on unknown channel id {m.channel_id}")
        messages.append(
            LogMessage(
                channel.topic, channel.schema_name, m.log_time, m.publish_time, m.sequence, m.data
            )
        )
    _check_statistics(statistics, raw_messages, name)
    return McapLog(
        name, header.profile, header.library, tuple(log_channels), tuple(messages), metadata
    )


def _channels(
    channels: dict[int, Channel], schemas: dict[int, Schema], name: str
) -> list[LogChannel]:
    out = []
    for channel in channels.values():
        schema = schemas.get(channel.schema_id)
        if schema is None:
            raise McapLogError(name, f"channel {channel.topic!r} has no schema record")
        out.append(
            LogChannel(
                channel.id,
                channel.topic,
                channel.message_encoding,
                schema.name,
                schema.encoding,
                schema.data,
                dict(channel.metadata),
            )
        )
    return out


def _check_statistics(statistics: Statistics | None, messages: list[Message], name: str) -> None:
    """The file's own statistics must match what was read: nothing silently missing."""
    if statistics is None:
        raise McapLogError(name, "incomplete MCAP file: no statistics record in the summary")
    counts = Counter(m.channel_id for m in messages)
    expected = {k: v for k, v in statistics.channel_message_counts.items() if v}
    if statistics.message_count != len(messages) or expected != dict(counts):
        raise McapLogError(
            name,
            f"incomplete MCAP file: statistics list {statistics.message_count} messages, "
            f"{len(messages)} were read",
        )


def read_log(path: str | Path) -> McapLog:
    """Read and verify an MCAP log file (raises McapLogError naming the file on any damage)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError as exc:
        raise McapLogError(str(path), "file not found") from exc
    except IsADirectoryError as exc:
        raise McapLogError(str(path), "is a folder, not an MCAP file") from exc
    return read_log_bytes(data, str(path))


def check_own_schema_versions(log: McapLog) -> None:
    """Every channel using one of the toolkit's own schemas must carry its current version."""
    for channel in log.channels:
        spec = topics.SCHEMAS.get(channel.schema_name)
        if spec is None or not spec.is_own:
            continue
        found = channel.metadata.get(topics.SCHEMA_VERSION_KEY)
        if found != str(spec.version):
            raise FormatVersionError(
                log.path,
                f"{channel.schema_name} {found}",
                f"{channel.schema_name} {spec.version}",
                _what_to_do(found, spec.version),
            )


def _what_to_do(found: object, expected: object) -> str:
    try:
        newer = int(str(found)) > int(str(expected))
    except ValueError:
        newer = False
    if newer:
        return "It was written by a newer skyvln-eval: upgrade skyvln-eval to read it."
    return (
        "Write it again with this version: an episode log with `skyvln-eval convert ...`, "
        "a run's logs by running it again into a new run directory."
    )


def episode_from_log(log: McapLog) -> Episode:
    """Rebuild the episode from a verified log's metadata (checks format and versions)."""
    meta = log.metadata.get(topics.EPISODE_METADATA)
    if meta is None:
        raise McapLogError(
            log.path, f"no {topics.EPISODE_METADATA!r} metadata record: not an episode log"
        )
    if meta.get("format") != topics.EPISODE_FORMAT:
        raise McapLogError(
            log.path, f"format is {meta.get('format')!r}, not {topics.EPISODE_FORMAT!r}"
        )
    version = meta.get("format_version")
    if version != str(topics.EPISODE_FORMAT_VERSION):
        raise FormatVersionError(
            log.path,
            version,
            topics.EPISODE_FORMAT_VERSION,
            _what_to_do(version, topics.EPISODE_FORMAT_VERSION),
        )
    check_own_schema_versions(log)
    mode = meta.get("mode")
    if mode not in EPISODE_MODES:
        raise McapLogError(log.path, f"metadata 'mode' is {mode!r}, not one of {EPISODE_MODES}")
    try:
        raw_records = json.loads(meta["records"])
    except (KeyError, json.JSONDecodeError) as exc:
        raise McapLogError(log.path, f"metadata 'records' is missing or not JSON: {exc}") from exc
    if not isinstance(raw_records, list) or not raw_records:
        raise McapLogError(log.path, "metadata 'records' is not a non-empty JSON list")
    records = tuple(parse_record(raw, log.path, i) for i, raw in enumerate(raw_records))
    episode = Episode(split=meta.get("split", ""), mode=mode, records=records)
    if episode.episode_id != meta.get("episode_id"):
        raise McapLogError(
            log.path,
            f"metadata episode_id {meta.get('episode_id')!r} does not match its records "
            f"({episode.episode_id!r})",
        )
    return episode


def read_episode(path: str | Path) -> Episode:
    """The episode stored in an episode log, equal (==) to what the AVDN reader produced."""
    return episode_from_log(read_log(path))


def read_episode_bytes(data: bytes, name: str = "<bytes>") -> Episode:
    return episode_from_log(read_log_bytes(data, name))
