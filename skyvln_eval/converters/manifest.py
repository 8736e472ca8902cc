"""The manifest of a converted split: one parquet row per episode log.

Columns: episode id, split, mode, map, rounds, GT views, GT length (m), D_net (m), file
name (relative to the manifest's folder), content hash (SHA-256 of the file), size, and
the input fingerprint that decides whether a re-run can skip the episode. The parquet
key-value metadata holds the manifest format version (checked on read) and the SHA-256 of
the ``left_out.json`` written beside it, so a folder whose list of what was left out went
missing or changed does not pass as complete.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from skyvln_eval.avdn import Episode, distance_m, view_centre
from skyvln_eval.errors import FormatVersionError, McapLogError
from skyvln_eval.fileio import atomic_write_bytes

MANIFEST_NAME: Final = "manifest.parquet"
#: 2: the SHA-256 of ``left_out.json`` is in the key-value metadata.
MANIFEST_VERSION: Final = 2
_VERSION_KEY: Final = b"skyvln_eval.manifest_version"
_LEFT_OUT_KEY: Final = b"skyvln_eval.left_out_sha256"


def episode_file_name(episode_id: str) -> str:
    """The log's file name: ``<episode_id>.mcap``."""
    # Episode ids are map_name__route_index with validated characters: safe as file names.
    return f"{episode_id}.mcap"


@dataclass(frozen=True)
class ManifestRow:
    """One converted episode. Lengths in metres on the official flat 111,300 m/deg."""

    episode_id: str
    split: str
    mode: str
    map_name: str
    rounds: int
    gt_views: int
    gt_length_m: float
    d_net_m: float
    file_name: str
    sha256: str
    size_bytes: int
    input_sha256: str


_SCHEMA: Final = pa.schema(
    [
        ("episode_id", pa.string()),
        ("split", pa.string()),
        ("mode", pa.string()),
        ("map_name", pa.string()),
        ("rounds", pa.int32()),
        ("gt_views", pa.int32()),
        ("gt_length_m", pa.float64()),
        ("d_net_m", pa.float64()),
        ("file_name", pa.string()),
        ("sha256", pa.string()),
        ("size_bytes", pa.int64()),
        ("input_sha256", pa.string()),
    ],
    metadata={_VERSION_KEY: str(MANIFEST_VERSION).encode()},
)


def gt_lengths_m(episode: Episode) -> tuple[float, float]:
    """(GT path length, D_net) in metres: sum of centre-to-centre steps, start to end."""
    centres = view_centre(episode.gt_path_corners)
    steps = distance_m(centres[1:], centres[:-1]) if len(centres) > 1 else np.zeros(0)
    return float(np.sum(steps)), float(distance_m(centres[0], centres[-1]))


def manifest_bytes(rows: Sequence[ManifestRow], left_out_sha256: str) -> bytes:
    """The manifest as parquet bytes (deterministic for a given pyarrow version);
    ``left_out_sha256`` is the hash of the ``left_out.json`` written beside it."""
    columns = {f.name: [getattr(r, f.name) for r in rows] for f in fields(ManifestRow)}
    schema = _SCHEMA.with_metadata(
        {**(_SCHEMA.metadata or {}), _LEFT_OUT_KEY: left_out_sha256.encode("ascii")}
    )
    table = pa.Table.from_pydict(columns, schema=schema)
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd")
    return sink.getvalue()


def write_manifest(path: str | Path, rows: Sequence[ManifestRow], left_out_sha256: str) -> None:
    atomic_write_bytes(path, manifest_bytes(rows, left_out_sha256))


def _checked_metadata(path: str | Path, schema: pa.Schema) -> dict[bytes, bytes]:
    metadata = schema.metadata or {}
    found = metadata.get(_VERSION_KEY)
    if found != str(MANIFEST_VERSION).encode():
        raise FormatVersionError(
            str(path),
            None if found is None else found.decode(errors="replace"),
            MANIFEST_VERSION,
            "Convert the split again with this version: `skyvln-eval convert ...`.",
        )
    return metadata


def manifest_left_out_sha256(path: str | Path) -> str:
    """SHA-256 of the ``left_out.json`` the conversion wrote beside the manifest; raises
    McapLogError (unreadable, or the hash is missing) or FormatVersionError."""
    try:
        schema = pq.read_schema(path)
    except (OSError, pa.ArrowException) as exc:
        raise McapLogError(str(path), f"manifest cannot be read as parquet: {exc}") from exc
    digest = _checked_metadata(path, schema).get(_LEFT_OUT_KEY)
    if digest is None:
        raise McapLogError(str(path), f"manifest lacks the metadata key {_LEFT_OUT_KEY.decode()}")
    return digest.decode("ascii", errors="replace")


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """Rows of a manifest; raises McapLogError (unreadable) or FormatVersionError."""
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise McapLogError(str(path), f"manifest cannot be read as parquet: {exc}") from exc
    _checked_metadata(path, table.schema)
    missing = [f.name for f in fields(ManifestRow) if f.name not in table.column_names]
    if missing:
        raise McapLogError(str(path), f"manifest lacks column(s) {missing}")
    return [
        ManifestRow(**{f.name: row[f.name] for f in fields(ManifestRow)})
        for row in table.to_pylist()
    ]
