"""Episode logs as a Hugging Face dataset and a parquet file."""

from __future__ import annotations

from pathlib import Path

import cv2
import datasets
import numpy as np

from skyvln_eval.avdn import observe_view, parse_record
from skyvln_eval.converters.batch import episode_file_name
from skyvln_eval.converters.hf import (
    export_parquet,
    read_episode_table,
    records_of_row,
    to_hf_dataset,
)
from skyvln_eval.frames import view_to_pose
from skyvln_eval.worlds import load_world
from tests.converters.conftest import ConvertedSample


def test_one_row_per_episode_with_gt_views_as_arrays(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    report = converted_sample.reports[("val_seen", "andh-full")]
    episodes = converted_sample.episodes[("val_seen", "andh-full")]
    table = to_hf_dataset(report.out_dir, include_observations=True)
    assert isinstance(table, datasets.Dataset) and table.num_rows == len(episodes)
    by_id = {e.episode_id: e for e in episodes}
    for row in table:
        episode = by_id[row["episode_id"]]
        views = episode.gt_path_corners
        assert row["gt_views_latlng"].dtype == np.float64
        assert row["gt_views_latlng"].shape == views.shape
        assert np.array_equal(row["gt_views_latlng"], views)
        pose = view_to_pose(views[-1], episode.georef)
        assert row["gt_poses_enu"][-1].tolist() == [pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad]
        assert [d["text"] for d in row["dialog"]] == [d.text for d in episode.dialog()]
        assert tuple(parse_record(r) for r in records_of_row(row)) == episode.records
        assert len(row["gt_observations"]) == len(views) and row["observation_format"] == "jpeg"
    # The first observation decodes to the official 224 x 224 warp (JPEG: close, not equal).
    first = table[0]
    episode = by_id[first["episode_id"]]
    world = load_world(converted_sample.data_dir, episode.map_name, episode.georef)
    image = cv2.imdecode(np.frombuffer(first["gt_observations"][0], np.uint8), cv2.IMREAD_COLOR)
    expected = observe_view(world.bgr, episode.start_view, episode.georef)
    assert image.shape == (224, 224, 3)
    assert np.mean(np.abs(image.astype(float) - expected)) < 6.0

    path = export_parquet(table, tmp_path / "tables" / "val_seen.parquet")
    back = datasets.Dataset.from_parquet(str(path))
    assert back.num_rows == table.num_rows and back.column_names == table.column_names
    assert [p.name for p in path.parent.iterdir()] == ["val_seen.parquet"]
    # Read back with the toolkit's reader, the arrays are the float64 written (datasets'
    # own NumPy format gave float32, ~0.4 m off in latitude), and the table says what it
    # holds and where each row came from.
    again = read_episode_table(path)
    for row, original in zip(again, table, strict=True):
        assert row["gt_views_latlng"].dtype == np.float64
        assert np.array_equal(row["gt_views_latlng"], original["gt_views_latlng"])
        assert len(row["input_sha256"]) == 64 and len(row["map_image_sha256"]) == 64
        assert row["toolkit_version"]
    assert "source's terms" in again.info.description


def test_a_list_of_files_without_observations(converted_sample: ConvertedSample) -> None:
    report = converted_sample.reports[("val_unseen", "andh")]
    paths = [
        report.out_dir / episode_file_name(e.episode_id)
        for e in converted_sample.episodes[("val_unseen", "andh")][:3]
    ]
    table = to_hf_dataset(paths)
    assert table.num_rows == 3 and "gt_observations" not in table.column_names
    assert table["file_name"] == [p.name for p in paths]


def test_a_folder_without_logs_is_refused_naming_the_folders_that_hold_some(
    converted_sample: ConvertedSample,
) -> None:
    # A convert --out root (or its split folder) gave an empty table without a word.
    import pytest

    from skyvln_eval.errors import DataError

    split_dir = converted_sample.reports[("val_seen", "andh")].out_dir.parent
    with pytest.raises(DataError, match=r"no episode logs \(\*\.mcap\) in this folder; these "
                       r"folders below it hold some: andh, andh-full"):  # fmt: skip
        to_hf_dataset(split_dir)
