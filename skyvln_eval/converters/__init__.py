"""Converters: AVDN episodes to Foxglove-ready MCAP episode logs, and back.

Follow one episode: :func:`convert_episode` writes it into an open
:class:`McapLogWriter` (a context manager that renames its temporary file into place only
on success); :func:`read_episode` verifies the file and returns an ``Episode`` equal to
the one the AVDN reader produced. Topic, schema and frame names live in :mod:`.topics`.
"""

from skyvln_eval.converters.convert import (
    CLOCK_STEP_NS,
    DEFAULT_OPTIONS,
    ConvertOptions,
    convert_episode,
    episode_metadata,
)
from skyvln_eval.converters.reader import (
    LogChannel,
    LogMessage,
    LogSummary,
    McapLog,
    episode_from_log,
    message_digest,
    read_episode,
    read_episode_bytes,
    read_log,
    read_log_bytes,
)
from skyvln_eval.converters.writer import McapLogWriter, encode_json

__all__ = [
    "CLOCK_STEP_NS",
    "DEFAULT_OPTIONS",
    "ConvertOptions",
    "LogChannel",
    "LogMessage",
    "LogSummary",
    "McapLog",
    "McapLogWriter",
    "convert_episode",
    "encode_json",
    "episode_from_log",
    "episode_metadata",
    "message_digest",
    "read_episode",
    "read_episode_bytes",
    "read_log",
    "read_log_bytes",
]
