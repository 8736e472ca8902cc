"""The manifest of a converted split: one parquet row per episode log.

Columns: episode id, split, mode, map, rounds, GT views, GT length (m), D_net (m), file
name (relative to the manifest's folder), content hash (SHA-256 of the file), size, and
the input fingerprint that decides whether a re-run can skip the episode. The manifest
format version is stored in the parquet key-value metadata and checked on read.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Final

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from skyvln_eval.avdn import Episode, distance_m, view_centre
from skyvln_eval.errors import FormatVersionError, McapLogError
from skyvln_eval.fileio import atomic_write_bytes

MANIFEST_NAME: Final = "manifest.parquet"
MANIFEST_VERSION: Final = 1
_VERSION_KEY: Final = b"skyvln_eval.manifest_version"


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


def manifest_bytes(rows: Sequence[ManifestRow]) -> bytes:
    """The manifest as parquet bytes (deterministic for a given pyarrow version)."""
    columns = {f.name: [getattr(r, f.name) for r in rows] for f in fields(ManifestRow)}
    table = pa.Table.from_pydict(columns, schema=_SCHEMA)
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd")
    return sink.getvalue()


def write_manifest(path: str | Path, rows: Sequence[ManifestRow]) -> None:
    atomic_write_bytes(path, manifest_bytes(rows))


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """Rows of a manifest; raises McapLogError (unreadable) or FormatVersionError."""
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise McapLogError(str(path), f"manifest cannot be read as parquet: {exc}") from exc
    found = (table.schema.metadata or {}).get(_VERSION_KEY)
    if found != str(MANIFEST_VERSION).encode():
        raise FormatVersionError(
            str(path),
            None if found is None else found.decode(errors="replace"),
            MANIFEST_VERSION,
            "Convert the split again with this version: `skyvln-eval convert ...`.",
        )
    missing = [f.name for f in fields(ManifestRow) if f.name not in table.column_names]
    if missing:
        raise McapLogError(str(path), f"manifest lacks column(s) {missing}")
    return [
        ManifestRow(**{f.name: row[f.name] for f in fields(ManifestRow)})
        for row in table.to_pylist()
    ]


def rows_as_dicts(rows: Sequence[ManifestRow]) -> list[dict[str, object]]:
    return [asdict(r) for r in rows]
