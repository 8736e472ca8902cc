"""Episode logs as a table: a Hugging Face ``datasets.Dataset``, one row per episode.

For users who prefer tables to logs. Rows are built from verified episode logs (so a
table can never hold what a damaged file would have given): ids, dialog, GT views as
arrays (``[lat, lng]`` degrees and ENU poses), lengths in metres, the verbatim source
records, and optionally the GT observation images (JPEG/PNG bytes). ``datasets`` is
imported only when these functions run.
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
    }
    if include_observations:
        images = [m.decode() for m in log.topic(topics.TOPIC_GT_OBSERVATION)]
        row["gt_observations"] = [base64.b64decode(m["data"]) for m in images]
        row["observation_format"] = images[0]["format"] if images else ""
    return row


def _log_paths(source: str | Path | Iterable[str | Path]) -> list[Path]:
    if isinstance(source, str | Path):
        source = Path(source)
        return sorted(source.glob("*.mcap")) if source.is_dir() else [source]
    return [Path(p) for p in source]


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
    table = datasets.Dataset.from_dict(columns, features=features)
    table.set_format(
        "numpy", columns=list(ARRAY_COLUMNS), output_all_columns=True, dtype=np.float64
    )
    return table


def export_parquet(dataset: datasets.Dataset, path: str | Path) -> Path:
    """Write a dataset as parquet to a temporary name, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        dataset.to_parquet(tmp)
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
