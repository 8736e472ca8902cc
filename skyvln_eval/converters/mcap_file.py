"""The MCAP file layout the toolkit writes, record by record, with a fast message path.

:class:`McapFileWriter` writes what ``mcap.writer.Writer`` writes with the options of
:class:`~skyvln_eval.converters.writer.McapLogWriter` (zstd chunks, message indexes after
each chunk, schemas, channels, statistics, chunk and metadata indexes repeated in the
summary, summary offsets, chunk, data-section and summary CRCs), byte for byte at the
library's compression level (the tests compare the two on the same input). The toolkit
writes its chunks at zstd level 1 (:data:`ZSTD_LEVEL`), not the library's 3.

Why not the library's writer: it builds a ``Message`` object, updates its statistics and
writes seven fields through a seeking buffer for every message, about 20 microseconds
each; a dynamics run log has a thousand messages per episode. Here a message is one
``struct.pack`` onto the open chunk and one entry in its index. Reading stays with the
``mcap`` library.

Record layouts follow the MCAP specification (https://mcap.dev/spec): an opcode byte, the
record's length as uint64, then its fields little-endian; strings and byte arrays are
prefixed with a uint32 length, maps with their byte length.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping
from typing import BinaryIO

import zstandard

MAGIC = b"\x89MCAP0\r\n"

#: The zstd level of the toolkit's chunks. On dynamics run logs (JSON text and JPEG
#: images, about 1.8 MB per episode) level 1 compressed in 3.1 ms per episode to 1/2.28
#: of the size, the library's level 3 in 5.8 ms to 1/2.19.
ZSTD_LEVEL = 1
#: What ``zstandard.compress``, and so ``mcap.writer.Writer``, uses.
LIBRARY_ZSTD_LEVEL = 3

# Opcodes of the specification.
HEADER = 0x01
FOOTER = 0x02
SCHEMA = 0x03
CHANNEL = 0x04
MESSAGE = 0x05
CHUNK = 0x06
MESSAGE_INDEX = 0x07
CHUNK_INDEX = 0x08
STATISTICS = 0x0B
ATTACHMENT_INDEX = 0x0A
METADATA = 0x0C
METADATA_INDEX = 0x0D
SUMMARY_OFFSET = 0x0E
DATA_END = 0x0F

#: Opcode, record length, channel id, sequence, log time, publish time.
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS_BYTES = _MESSAGE_HEAD.size - 9


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def _string(value: str) -> bytes:
    encoded = value.encode()
    return struct.pack("<I", len(encoded)) + encoded


def _string_map(values: Mapping[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in values.items())
    return struct.pack("<I", len(body)) + body


def _id_map(values: Mapping[int, int]) -> bytes:
    """A map of uint16 ids to uint64 values (statistics' message counts, chunk indexes'
    message index offsets), in the mapping's order."""
    body = b"".join(struct.pack("<HQ", k, v) for k, v in values.items())
    return struct.pack("<I", len(body)) + body


class McapFileWriter:
    """Write one MCAP stream: :meth:`start`, then schemas, channels, messages and metadata
    in any order (a channel after its schema, a message after its channel), then
    :meth:`finish`. Ids are given out from 1 in registration order, as the library does.
    Log times must never decrease (the log writer checks), so a chunk's and the file's
    time range run from their first message to their last.

    Offsets are counted from the stream's position at construction (0 on a stream that
    cannot tell it, such as a pipe: the library's writer fails there).
    """

    def __init__(
        self,
        stream: BinaryIO,
        chunk_size_bytes: int,
        profile: str,
        library: str,
        zstd_level: int = ZSTD_LEVEL,
    ) -> None:
        self._stream = stream
        self._compressor = zstandard.ZstdCompressor(level=zstd_level)
        try:
            self._offset = stream.tell()
        except OSError:  # io.UnsupportedOperation included: a pipe, a socket
            self._offset = 0
        self._chunk_size = chunk_size_bytes
        self._profile, self._library = profile, library
        self._data_crc = 0
        self._schemas: list[bytes] = []
        self._channels: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._message_counts: dict[int, int] = {}
        self._message_count = 0
        self._message_start = 0
        self._message_end = 0
        self._metadata_count = 0
        self._chunk_count = 0
        self._chunk = bytearray()  # the open chunk's records, uncompressed
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._chunk_index: dict[int, list[int]] = {}  # channel -> [time, offset, time, ...]

    def _write(self, data: bytes) -> None:
        """Into the data section (counted in its CRC)."""
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._stream.write(data)
        self._offset += len(data)

    def start(self) -> None:
        self._write(MAGIC)
        self._write(_record(HEADER, _string(self._profile) + _string(self._library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        body = struct.pack("<H", schema_id) + _string(name) + _string(encoding)
        record = _record(SCHEMA, body + struct.pack("<I", len(data)) + data)
        self._schemas.append(record)
        self._into_chunk(record)
        return schema_id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]
    ) -> int:
        channel_id = len(self._channels) + 1
        body = struct.pack("<HH", channel_id, schema_id) + _string(topic)
        record = _record(CHANNEL, body + _string(message_encoding) + _string_map(metadata))
        self._channels.append(record)
        self._into_chunk(record)
        return channel_id

    def _into_chunk(self, record: bytes) -> None:
        self._chunk += record
        if len(self._chunk) > self._chunk_size:
            self._finish_chunk()

    def add_message(self, channel_id: int, log_time: int, data: bytes, sequence: int) -> None:
        """A message whose publish time is its log time."""
        chunk = self._chunk
        index = self._chunk_index.get(channel_id)
        if index is None:
            index = self._chunk_index[channel_id] = []
        index += (log_time, len(chunk))
        chunk += _MESSAGE_HEAD.pack(
            MESSAGE, _MESSAGE_FIELDS_BYTES + len(data), channel_id, sequence, log_time, log_time
        )
        chunk += data
        if not self._chunk_messages:
            self._chunk_start = log_time
            if not self._message_count:
                self._message_start = log_time
        self._chunk_end = self._message_end = log_time
        self._chunk_messages += 1
        self._message_count += 1
        self._message_counts[channel_id] = self._message_counts.get(channel_id, 0) + 1
        if len(chunk) > self._chunk_size:
            self._finish_chunk()

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        """A metadata record, in the data section between chunks (the open one goes on)."""
        record = _record(METADATA, _string(name) + _string_map(values))
        self._metadata_indexes.append(
            _record(METADATA_INDEX, struct.pack("<QQ", self._offset, len(record)) + _string(name))
        )
        self._metadata_count += 1
        self._write(record)

    def _finish_chunk(self) -> None:
        """Write the open chunk and its message indexes (a chunk without messages stays
        open: its schemas and channels go into the next one)."""
        if not self._chunk_messages:
            return
        self._chunk_count += 1
        records = bytes(self._chunk)
        compressed = self._compressor.compress(records)
        times = struct.pack("<QQ", self._chunk_start, self._chunk_end)
        sizes = struct.pack("<QI", len(records), zlib.crc32(records))
        chunk = _record(
            CHUNK, times + sizes + _string("zstd") + struct.pack("<Q", len(compressed)) + compressed
        )
        chunk_offset = self._offset
        self._write(chunk)
        index_offsets: dict[int, int] = {}
        indexes = bytearray()
        for channel_id, entries in self._chunk_index.items():
            index_offsets[channel_id] = self._offset + len(indexes)
            pairs = struct.pack(f"<{len(entries)}Q", *entries)
            body = struct.pack("<HI", channel_id, len(pairs)) + pairs
            indexes += _record(MESSAGE_INDEX, body)
        self._write(bytes(indexes))
        self._chunk_indexes.append(
            _record(
                CHUNK_INDEX,
                times
                + struct.pack("<QQ", chunk_offset, len(chunk))
                + _id_map(index_offsets)
                + struct.pack("<Q", len(indexes))
                + _string("zstd")
                + struct.pack("<QQ", len(compressed), len(records)),
            )
        )
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = self._chunk_end = 0
        self._chunk_index = {}

    def finish(self) -> None:
        """The last chunk, the data end, the summary, its offsets, the footer, the magic."""
        self._finish_chunk()
        self._write(_record(DATA_END, struct.pack("<I", self._data_crc)))
        summary_start = self._offset
        statistics = _record(
            STATISTICS,
            struct.pack(
                "<QHIIIIQQ",
                self._message_count,
                len(self._schemas),
                len(self._channels),
                0,  # attachments
                self._metadata_count,
                self._chunk_count,
                self._message_start,
                self._message_end,
            )
            + _id_map(self._message_counts),
        )
        groups = (
            (SCHEMA, b"".join(self._schemas)),
            (CHANNEL, b"".join(self._channels)),
            (STATISTICS, statistics),
            (CHUNK_INDEX, b"".join(self._chunk_indexes)),
            (ATTACHMENT_INDEX, b""),  # none, but the library lists the group
            (METADATA_INDEX, b"".join(self._metadata_indexes)),
        )
        summary = bytearray()
        offsets = bytearray()
        for opcode, group in groups:
            group_start = summary_start + len(summary)
            offsets += _record(SUMMARY_OFFSET, struct.pack("<BQQ", opcode, group_start, len(group)))
            summary += group
        summary_offset_start = summary_start + len(summary)
        summary += offsets
        footer_fields = struct.pack("<QQ", summary_start, summary_offset_start)
        # The summary CRC covers the summary and the footer's fields before the CRC itself.
        footer_head = struct.pack("<BQ", FOOTER, len(footer_fields) + 4)
        summary_crc = zlib.crc32(footer_head + footer_fields, zlib.crc32(summary))
        self._stream.write(bytes(summary))
        self._stream.write(_record(FOOTER, footer_fields + struct.pack("<I", summary_crc)))
        self._stream.write(MAGIC)
