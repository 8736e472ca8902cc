"""The toolkit's MCAP writer writes what the mcap library's writer writes: byte for byte at
the library's zstd level, and the same records at the toolkit's."""

from __future__ import annotations

import io
import random
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer

from skyvln_eval.converters.mcap_file import LIBRARY_ZSTD_LEVEL, ZSTD_LEVEL, McapFileWriter

PROFILE, LIBRARY = "test-profile", "test-library"


class _Library:
    """mcap.writer.Writer with McapLogWriter's options, behind McapFileWriter's calls."""

    def __init__(self, stream: io.BytesIO, chunk_size: int) -> None:
        self._writer = Writer(
            stream,
            chunk_size=chunk_size,
            compression=CompressionType.ZSTD,
            index_types=IndexType.ALL,
            repeat_channels=True,
            repeat_schemas=True,
            use_chunking=True,
            use_statistics=True,
            use_summary_offsets=True,
            enable_crcs=True,
            enable_data_crcs=True,
        )

    def start(self) -> None:
        self._writer.start(profile=PROFILE, library=LIBRARY)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        return int(self._writer.register_schema(name=name, encoding=encoding, data=data))

    def register_channel(self, topic: str, encoding: str, schema_id: int, meta: Any) -> int:
        return int(self._writer.register_channel(topic, encoding, schema_id, dict(meta)))

    def add_message(self, channel_id: int, log_time: int, data: bytes, sequence: int) -> None:
        self._writer.add_message(channel_id, log_time, data, log_time, sequence)

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self._writer.add_metadata(name, values)

    def finish(self) -> None:
        self._writer.finish()


def _write(
    kind: str,
    seed: int,
    chunk_size: int,
    messages: int,
    prefix: bytes = b"",
    level: int = 0,
    stream: io.BytesIO | None = None,
) -> bytes:
    """A seeded mix of schemas, channels, messages (times never decreasing, as the log
    writer requires) and metadata, written by either writer after ``prefix``."""
    rng = random.Random(seed)
    stream = stream or io.BytesIO()
    stream.write(prefix)
    writer: Any = (
        McapFileWriter(stream, chunk_size, PROFILE, LIBRARY, level or LIBRARY_ZSTD_LEVEL)
        if kind == "ours"
        else _Library(stream, chunk_size)
    )
    writer.start()
    channels: list[int] = []
    schemas: list[int] = []
    t_ns = 0
    if rng.random() < 0.5:
        writer.add_metadata("first", {"a": "1", "ü": "ä"})
    for sequence in range(messages):
        roll = rng.random()
        if not schemas or roll < 0.03:
            data = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 60)))
            schemas.append(writer.register_schema(f"schema{len(schemas)}", "jsonschema", data))
        if not channels or roll < 0.08:
            meta = {"version": str(rng.randrange(5))} if rng.random() < 0.5 else {}
            schema_id = rng.choice([*schemas, 0])
            channels.append(writer.register_channel(f"/t{len(channels)}", "json", schema_id, meta))
        if roll > 0.97:
            writer.add_metadata(f"meta{sequence}", {"k": str(sequence)})
        t_ns += rng.choice([0, 0, 1, 10**6, 10**9 + 7])
        size = rng.choice([0, 5, 40, 300, 5000])
        writer.add_message(rng.choice(channels), t_ns, rng.randbytes(size), sequence)
    writer.finish()
    return stream.getvalue()


@pytest.mark.parametrize(
    ("seed", "chunk_size", "messages"),
    [(0, 1 << 20, 300), (1, 4096, 400), (2, 1, 50), (3, 1 << 20, 0), (4, 2000, 1000)],
)
def test_same_bytes_as_the_mcap_library(seed: int, chunk_size: int, messages: int) -> None:
    ours = _write("ours", seed, chunk_size, messages)
    assert ours == _write("library", seed, chunk_size, messages)
    # And the library reads it back: every message, in order, with its summary.
    reader = make_reader(io.BytesIO(ours), validate_crcs=True)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == messages
    read = [m.sequence for _, _, m in reader.iter_messages(log_time_order=False)]
    assert sorted(read) == list(range(messages))
    if chunk_size == 1 and messages:
        assert summary.statistics.chunk_count == messages  # every message closed a chunk


def _records(data: bytes) -> list[Any]:
    """Every record of a file, chunks opened, without the fields that depend on the
    compressed sizes (offsets in the file, lengths of chunks, CRCs over them)."""
    varying = {
        "compressed_size",
        "chunk_start_offset",
        "chunk_length",
        "message_index_offsets",
        "data_section_crc",
        "group_start",
        "offset",
        "summary_start",
        "summary_offset_start",
        "summary_crc",
    }
    out = []
    for record in StreamReader(io.BytesIO(data), emit_chunks=False).records:
        fields = {k: v for k, v in vars(record).items() if k not in varying}
        out.append((type(record).__name__, fields))
    return out


def test_the_toolkits_level_changes_only_the_compressed_bytes() -> None:
    ours = _write("ours", 6, 5000, 600, level=ZSTD_LEVEL)
    library = _write("library", 6, 5000, 600)
    assert ours != library
    assert _records(ours) == _records(library)


def test_offsets_count_from_where_the_stream_was() -> None:
    prefix = b"not part of the file"
    ours = _write("ours", 5, 3000, 200, prefix)
    assert ours == _write("library", 5, 3000, 200, prefix)


class _Pipe(io.BytesIO):
    """A stream that cannot tell its position, as a pipe."""

    def tell(self) -> int:
        raise io.UnsupportedOperation("not seekable")


def test_a_stream_without_a_position_gets_the_file_as_from_offset_zero() -> None:
    assert _write("ours", 7, 3000, 100, stream=_Pipe()) == _write("ours", 7, 3000, 100)
