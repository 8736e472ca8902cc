"""The MCAP log writer shared by episode logs (converters) and run logs (replay harness).

A :class:`McapLogWriter` is a context manager. Given a path, it writes to a temporary
file in the same folder and renames it into place only when the block ends without an
exception, so an interrupted or failed write never leaves a file under the final name.
Given a binary stream (e.g. ``io.BytesIO``), it writes there directly (tests, pipes).

Files are deterministic: fixed header strings, no wall clock, schemas and channels
registered lazily in first-use order with ids counted from 1, messages serialised as
compact JSON in insertion order, zstd chunks (deterministic at a fixed level), every
index, chunk CRCs and the data-section CRC: the layout of ``mcap.writer.Writer`` with
those options, written by :mod:`.mcap_file` (faster per message). Log times are integer
nanoseconds on the caller's deterministic clock and must never decrease: static content
(log time 0) goes first, then time-ordered messages.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np

from skyvln_eval.converters import topics
from skyvln_eval.converters.mcap_file import McapFileWriter
from skyvln_eval.errors import ConfigError, McapLogError
from skyvln_eval.fileio import usual_permissions

#: Chunks of this many uncompressed bytes; an episode log usually fits in one or two.
DEFAULT_CHUNK_SIZE_BYTES = 1 << 20


def _json_default(value: Any) -> Any:
    # NumPy scalars and arrays are common in geometry code; encode them as plain JSON.
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def encode_json(message: Any) -> bytes:
    """A message as compact UTF-8 JSON (keys in insertion order; NaN is refused)."""
    return json.dumps(
        message, separators=(",", ":"), ensure_ascii=False, allow_nan=False, default=_json_default
    ).encode("utf-8")


class McapLogWriter:
    """Write one MCAP log: ``with McapLogWriter(path) as log: log.write(...)``.

    ``write(topic, schema_name, message, log_time_ns)`` takes a JSON-serialisable message
    (or its already-encoded JSON bytes); the topic must be declared in
    :mod:`skyvln_eval.converters.topics` with that schema. ``add_metadata`` writes a
    name -> (str -> str) record. ``sha256`` is not computed here: hash the final file.
    """

    def __init__(
        self, target: str | Path | BinaryIO, chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES
    ) -> None:
        self._final_path: Path | None = None
        self._stream: BinaryIO | None = None
        self._tmp_path: Path | None = None
        if isinstance(target, str | Path):
            self._final_path = Path(target)
        else:
            self._stream = target
        self._chunk_size_bytes = chunk_size_bytes
        self._writer: McapFileWriter | None = None
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._last_log_time_ns = 0
        self._sequence = 0

    @property
    def name(self) -> str:
        """The file name for messages (the final path), or ``<stream>``."""
        return str(self._final_path) if self._final_path is not None else "<stream>"

    @property
    def message_count(self) -> int:
        return self._sequence

    def __enter__(self) -> McapLogWriter:
        if self._final_path is not None:
            self._final_path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(
                prefix=f".{self._final_path.name}.", suffix=".tmp", dir=self._final_path.parent
            )
            self._tmp_path = Path(tmp)
            self._stream = os.fdopen(fd, "wb")
        assert self._stream is not None  # one of the two branches above set it
        self._writer = McapFileWriter(
            self._stream, self._chunk_size_bytes, topics.MCAP_PROFILE, topics.MCAP_LIBRARY
        )
        self._writer.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            try:
                self._live().finish()
            except BaseException:
                self._discard()
                raise
            self._writer = None
            if self._tmp_path is not None and self._final_path is not None:
                assert self._stream is not None
                self._stream.close()
                usual_permissions(self._tmp_path)  # as the other files of a run, not 0600
                self._tmp_path.replace(self._final_path)
                self._tmp_path = None
            return
        self._discard()

    def _discard(self) -> None:
        """Drop a failed file: close and delete the temporary file (never the final name)."""
        self._writer = None
        if self._tmp_path is not None:
            if self._stream is not None:
                self._stream.close()
            self._tmp_path.unlink(missing_ok=True)
            self._tmp_path = None

    def _live(self) -> McapFileWriter:
        if self._writer is None:
            raise ConfigError("McapLogWriter is not open: use it as `with McapLogWriter(...)`")
        return self._writer

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        """A metadata record (all values strings, as MCAP requires)."""
        bad = [k for k, v in values.items() if not isinstance(v, str)]
        if bad:
            raise ConfigError(f"metadata {name!r}: values of {bad} are not strings")
        self._live().add_metadata(name, dict(values))

    def _channel(self, topic: str, schema_name: str) -> int:
        channel_id = self._channel_ids.get(topic)
        if channel_id is not None:
            return channel_id
        declared = topics.TOPICS.get(topic)
        if declared is None:
            raise ConfigError(f"topic {topic!r} is not declared in skyvln_eval.converters.topics")
        if declared != schema_name:
            raise ConfigError(
                f"topic {topic!r} is declared with schema {declared!r}, not {schema_name!r}"
            )
        spec = topics.SCHEMAS[schema_name]
        writer = self._live()
        schema_id = self._schema_ids.get(schema_name)
        if schema_id is None:
            schema_id = writer.register_schema(
                name=spec.name,
                encoding=topics.SCHEMA_ENCODING,
                data=topics.schema_bytes(spec.name),
            )
            self._schema_ids[schema_name] = schema_id
        metadata = {topics.SCHEMA_VERSION_KEY: str(spec.version)} if spec.is_own else {}
        channel_id = writer.register_channel(
            topic=topic,
            message_encoding=topics.MESSAGE_ENCODING,
            schema_id=schema_id,
            metadata=metadata,
        )
        self._channel_ids[topic] = channel_id
        return channel_id

    def write(self, topic: str, schema_name: str, message: Any, log_time_ns: int) -> None:
        """Append one message; ``log_time_ns`` is also its publish time.

        Messages get consecutive sequence numbers from 0 in write order, so any reader
        can restore the write order whatever order it returns messages in.
        """
        if type(log_time_ns) is not int or log_time_ns < 0:
            raise ConfigError(f"log_time_ns must be a non-negative int, got {log_time_ns!r}")
        if log_time_ns < self._last_log_time_ns:
            raise ConfigError(
                f"{self.name}: message on {topic!r} at {log_time_ns} ns goes back in time "
                f"(last was {self._last_log_time_ns} ns); write static content first, "
                "then messages in time order"
            )
        channel_id = self._channel(topic, schema_name)
        if isinstance(message, bytes | bytearray | memoryview):
            data = bytes(message)
        else:
            try:
                data = encode_json(message)
            except (TypeError, ValueError) as exc:
                raise McapLogError(
                    self.name, f"message on {topic!r} at {log_time_ns} ns cannot be encoded: {exc}"
                ) from exc
        self._live().add_message(channel_id, log_time_ns, data, self._sequence)
        self._sequence += 1
        self._last_log_time_ns = log_time_ns
