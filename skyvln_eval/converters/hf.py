"""Episode logs as a table: a Hugging Face ``datasets.Dataset``, one row per episode.

For users who prefer tables to logs. Rows are built from verified episode logs (so a
table can never hold what a damaged file would have given): ids, dialog, GT views as
arrays (``[lat, lng]`` degrees and ENU poses), lengths in metres, the source
records as parsed, and optionally the GT observation images (JPEG/PNG bytes), and where each row
came from: the log's toolkit version and, for a log ``convert`` wrote, the fingerprint of
its input (records, map image, options) and of its map image. ``datasets`` is imported
only when these functions run.

The rows hold their source's data: the AVDN records (and, with observations, crops of
the map images: xView's for the real dataset) come under their own terms, which the
table's description repeats; the synthetic sample is the toolkit's own.
"""

from __future__ import annotations

import base64
import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skyvln_eval.converters import topics
from skyvln_eval.converters.manifest import gt_lengths_m
from skyvln_eval.converters.reader import episode_from_log, read_log
from skyvln_eval.errors import DataError
from skyvln_eval.fileio import usual_permissions
from skyvln_eval.frames import view_to_pose

if TYPE_CHECKING:
    import datasets

#: Columns returned as float64 NumPy arrays.
ARRAY_COLUMNS = ("gt_views_latlng", "gt_poses_enu")


def _features(include_observations: bool) -> datasets.Features:
    import datasets

    columns: dict[str, Any] = {
        "episode_id": datasets.Value("string"),
        "split": datasets.Value("string"),
        "mode": datasets.Value("string"),
        "map_name": datasets.Value("string"),
        "rounds": datasets.Value("int32"),
        # A Python list of a dict is a list of structs (a Sequence of a dict is a struct of lists).
        "dialog": [
            {
                "round_index": datasets.Value("int32"),
                "speaker": datasets.Value("string"),
                "text": datasets.Value("string"),
            }
        ],
        "start_heading_deg": datasets.Value("int32"),
        "gt_views_latlng": datasets.Array3D(shape=(None, 4, 2), dtype="float64"),
        "gt_poses_enu": datasets.Array2D(shape=(None, 4), dtype="float64"),
        "destination_latlng": datasets.Sequence(datasets.Sequence(datasets.Value("float64"))),
        "gt_length_m": datasets.Value("float64"),
        "d_net_m": datasets.Value("float64"),
        "records_json": datasets.Value("string"),
        "file_name": datasets.Value("string"),
        "toolkit_version": datasets.Value("string"),
        "input_sha256": datasets.Value("string"),
        "map_image_sha256": datasets.Value("string"),
    }
    if include_observations:
        columns["gt_observations"] = datasets.Sequence(datasets.Value("binary"))
        columns["observation_format"] = datasets.Value("string")
    return datasets.Features(columns)


def episode_row(path: str | Path, include_observations: bool = False) -> dict[str, Any]:
    """One table row from one episode log (verified as :func:`read_log` does).

    ``gt_poses_enu`` columns are x_m, y_m, z_m (height = edge / 2) and yaw_rad, in the ENU
    ``map`` frame of :mod:`skyvln_eval.frames`.
    """
    log = read_log(path)
    episode = episode_from_log(log)
    conversion = log.metadata.get(topics.CONVERSION_METADATA, {})
    views = episode.gt_path_corners
    poses = [view_to_pose(v, episode.georef) for v in views]
    gt_length, d_net = gt_lengths_m(episode)
    destination = episode.destination
    row: dict[str, Any] = {
        "episode_id": episode.episode_id,
        "split": episode.split,
        "mode": episode.mode,
        "map_name": episode.map_name,
        "rounds": episode.records[-1].round_index,
        "dialog": [
            {"round_index": d.round_index, "speaker": d.speaker, "text": d.text}
            for d in episode.dialog()
        ],
        "start_heading_deg": episode.start_heading_deg,
        "gt_views_latlng": np.asarray(views, dtype=np.float64),
        "gt_poses_enu": np.array(
            [[p.x_m, p.y_m, p.z_m, p.yaw_rad] for p in poses], dtype=np.float64
        ),
        "destination_latlng": None if destination is None else destination.tolist(),
        "gt_length_m": gt_length,
        "d_net_m": d_net,
        "records_json": log.metadata[topics.EPISODE_METADATA]["records"],
        "file_name": Path(path).name,
        "toolkit_version": log.metadata[topics.EPISODE_METADATA].get("toolkit_version", ""),
        # "" for a log not written by `convert` (a run's episode log has no conversion).
        "input_sha256": conversion.get("input_sha256", ""),
        "map_image_sha256": conversion.get("map_image_sha256", ""),
    }
    if include_observations:
        images = [m.decode() for m in log.topic(topics.TOPIC_GT_OBSERVATION)]
        if not images:  # the row would say nothing of why it holds none
            raise DataError(
                f"{path}: no ground-truth observations to include (converted with "
                "--no-observations?): convert with them, or leave include_observations off"
            )
        row["gt_observations"] = [base64.b64decode(m["data"]) for m in images]
        row["observation_format"] = images[0]["format"]
    return row


def _log_paths(source: str | Path | Iterable[str | Path]) -> list[Path]:
    """The logs of ``source``: a file, a list, or the ``.mcap`` files directly in a folder
    (one without any is refused, naming the folders below it that hold some: a
    ``convert --out`` root or its split folder gave an empty table without a word)."""
    if not isinstance(source, str | Path):
        return [Path(p) for p in source]
    source = Path(source)
    if not source.is_dir():
        return [source]
    found = sorted(source.glob("*.mcap"))
    if not found:
        below = sorted({str(p.parent.relative_to(source)) for p in source.rglob("*.mcap")})
        hint = f"; these folders below it hold some: {', '.join(below[:5])}" if below else ""
        raise DataError(f"{source}: no episode logs (*.mcap) in this folder{hint}")
    return found


def to_hf_dataset(
    source: str | Path | Iterable[str | Path], include_observations: bool = False
) -> datasets.Dataset:
    """A ``datasets.Dataset`` of episodes from a folder of logs (sorted by name) or a list.

    The array columns come back as float64 NumPy arrays (``datasets``' NumPy format would
    otherwise cast them to float32, which loses about a metre in latitude); other columns
    are plain Python values.
    """
    import datasets

    rows = [episode_row(p, include_observations) for p in _log_paths(source)]
    features = _features(include_observations)
    columns = {name: [row[name] for row in rows] for name in features}
    info = datasets.DatasetInfo(description=DESCRIPTION, features=features)
    return _float64_arrays(datasets.Dataset.from_dict(columns, info=info))


#: The table's description (kept in its parquet file's metadata).
DESCRIPTION = (
    "AVDN-format aerial vision-and-dialog navigation episodes, one row per episode, "
    "converted from episode logs by skyvln-eval. The records and images keep their "
    "source's terms: the AVDN annotations and xView imagery for the real dataset, the "
    "toolkit's own for its synthetic sample. gt_views_latlng: each view's four corners "
    "[lat, lng] in degrees; gt_poses_enu: x_m, y_m, z_m (height = edge / 2), yaw_rad in "
    "the map's ENU frame; lengths in metres; records_json: the source records as parsed "
    "(compact JSON); "
    "input_sha256 / map_image_sha256: the conversion's input and map image."
)


def _float64_arrays(table: datasets.Dataset) -> datasets.Dataset:
    table.set_format(
        "numpy", columns=list(ARRAY_COLUMNS), output_all_columns=True, dtype=np.float64
    )
    return table


#: The parquet metadata key of the table's description (``datasets`` keeps only features).
DESCRIPTION_KEY = b"skyvln_eval.description"


def _describe_parquet(path: Path, description: str) -> None:
    """Put ``description`` into the parquet file's metadata (rewritten in place)."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    metadata = {**(table.schema.metadata or {}), DESCRIPTION_KEY: description.encode()}
    pq.write_table(table.replace_schema_metadata(metadata), path)


def read_episode_table(path: str | Path) -> datasets.Dataset:
    """A table :func:`export_parquet` wrote, with its description, its array columns
    float64 as written (``datasets``' own reading gives float32 in NumPy format: about a
    metre off)."""
    import datasets
    import pyarrow.parquet as pq

    table = datasets.Dataset.from_parquet(str(path))
    described = (pq.read_schema(path).metadata or {}).get(DESCRIPTION_KEY)
    if described is not None:
        table.info.description = described.decode()
    return _float64_arrays(table)


def export_parquet(dataset: datasets.Dataset, path: str | Path) -> Path:
    """Write a dataset as parquet to a temporary name, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        dataset.to_parquet(tmp)
        _describe_parquet(Path(tmp), dataset.info.description or DESCRIPTION)
        usual_permissions(tmp)
        Path(tmp).replace(path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def records_of_row(row: dict[str, Any]) -> list[dict[str, Any]]:
    """The verbatim AVDN records of a table row (parse them with ``avdn.parse_record``)."""
    records: list[dict[str, Any]] = json.loads(row["records_json"])
    return records
