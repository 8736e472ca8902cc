"""Converters: AVDN episodes to Foxglove-ready MCAP episode logs, and back.

Follow one episode: :func:`convert_episode` writes it into an open
:class:`McapLogWriter` (a context manager that renames its temporary file into place only
on success); :func:`read_episode` verifies the file and returns an ``Episode`` equal to
the one the AVDN reader produced. Topic, schema and frame names live in :mod:`.topics`.
"""

from skyvln_eval.converters.batch import (
    ConvertReport,
    EpisodeOutcome,
    convert_split,
    split_output_dir,
)
from skyvln_eval.converters.convert import (
    CLOCK_STEP_NS,
    DEFAULT_OPTIONS,
    ConvertOptions,
    convert_episode,
    episode_metadata,
)
from skyvln_eval.converters.hf import export_parquet, read_episode_table, to_hf_dataset
from skyvln_eval.converters.left_out import LEFT_OUT_NAME, LeftOut, read_left_out
from skyvln_eval.converters.manifest import (
    MANIFEST_NAME,
    ManifestRow,
    episode_file_name,
    read_manifest,
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
from skyvln_eval.converters.validate import LogCheck, check_log, check_paths
from skyvln_eval.converters.writer import McapLogWriter, encode_json

__all__ = [
    "CLOCK_STEP_NS",
    "DEFAULT_OPTIONS",
    "LEFT_OUT_NAME",
    "MANIFEST_NAME",
    "ConvertOptions",
    "ConvertReport",
    "EpisodeOutcome",
    "LeftOut",
    "LogChannel",
    "LogCheck",
    "LogMessage",
    "LogSummary",
    "ManifestRow",
    "McapLog",
    "McapLogWriter",
    "check_log",
    "check_paths",
    "convert_episode",
    "convert_split",
    "encode_json",
    "episode_file_name",
    "episode_from_log",
    "episode_metadata",
    "export_parquet",
    "message_digest",
    "read_episode",
    "read_episode_bytes",
    "read_episode_table",
    "read_left_out",
    "read_log",
    "read_log_bytes",
    "read_manifest",
    "split_output_dir",
    "to_hf_dataset",
]
