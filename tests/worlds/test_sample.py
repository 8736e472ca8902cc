"""The bundled synthetic sample: AVDN layout, exact GT replay, seen/unseen maps, dialogs."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.avdn import SPLITS, hull_iou, load_split, replay_ground_truth, view_centre
from skyvln_eval.avdn.geometry import view_heading_deg
from skyvln_eval.avdn.step import action_between_views
from skyvln_eval.worlds import load_world
from skyvln_eval.worlds.sample import DatasetSpec, build_dataset
from tests.conftest import CliOutcome

Cli = Callable[..., CliOutcome]


@pytest.fixture(scope="module")
def splits(sample_dir: Path):
    return {split: load_split(sample_dir, split) for split in SPLITS}


def test_layout_is_avdn(sample_dir: Path) -> None:
    for split in SPLITS:
        data = json.loads((sample_dir / "annotations" / f"{split}_data.json").read_text())
        assert isinstance(data, list) and data
    maps = {p.stem for p in (sample_dir / "train_images").glob("*.tif")}
    assert len(maps) == 7 and all(m.isdigit() for m in maps)


def test_every_split_loads_without_issues(splits) -> None:
    for split, loaded in splits.items():
        assert loaded.skipped == ()
        assert 20 <= len(loaded.records) <= 60, split
        assert not loaded.ground_truth_withheld  # synthetic test_unseen keeps its GT


def test_ground_truth_replay_gives_hull_iou_one(splits) -> None:
    count = 0
    for loaded in splits.values():
        for r in loaded.records:
            replayed = replay_ground_truth(r.gt_path_corners, r.gps_botm_left, r.gps_top_right)
            assert hull_iou(replayed[-1], r.gt_path_corners[-1]) > 1 - 1e-9, r.episode_id
            count += 1
    assert count == sum(len(s.records) for s in splits.values())


def test_ground_truth_moves_like_the_official_step(splits) -> None:
    for r in splits["val_unseen"].records:
        for a, b in zip(r.gt_path_corners[:-1], r.gt_path_corners[1:], strict=True):
            action = action_between_views(a, b)
            assert max(abs(action.waypoint[0]), abs(action.waypoint[1])) <= 1.0 + 1e-9
            assert 0.0 <= action.altitude <= 1.0


def test_seen_maps_are_shared_and_unseen_maps_are_not(splits) -> None:
    maps = {split: set(loaded.map_names()) for split, loaded in splits.items()}
    assert maps["val_seen"] <= maps["train"]
    assert not maps["val_unseen"] & (maps["train"] | maps["test_unseen"])
    assert not maps["test_unseen"] & maps["train"]


def test_paths_views_and_lengths_are_realistic(splits) -> None:
    lengths, edges = [], []
    for loaded in splits.values():
        for r in loaded.records:
            c = view_centre(r.gt_path_corners)
            lengths.append(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() * 111_300)
            edges.extend(
                np.linalg.norm(r.gt_path_corners[:, 0] - r.gt_path_corners[:, 1], axis=1) * 111_300
            )
    assert 100 < np.mean(lengths) < 260  # AVDN: about 150 m per sub-trajectory
    assert min(edges) >= 40 and max(edges) <= 400


def test_dialogs_follow_the_avdn_format(splits) -> None:
    for loaded in splits.values():
        for key, rounds in loaded.trajectories().items():
            assert [r.round_index for r in rounds] == list(range(1, len(rounds) + 1)), key
            assert all(r.last_round_idx == len(rounds) for r in rounds)
            for k, r in enumerate(rounds):
                assert list(r.pre_dialogs) == [x.instructions for x in rounds[:k]]
                if k == 0:
                    assert r.instructions.startswith("[INS] ")
                else:
                    assert r.instructions.startswith("[QUE] ") and " [INS] " in r.instructions
                    prev = rounds[k - 1]
                    assert np.array_equal(r.gt_path_corners[0], prev.gt_path_corners[-1])
                    assert len(r.attention_list) > len(prev.attention_list)
                    assert r.attention_list[: len(prev.attention_list)] == prev.attention_list
            assert rounds[-1].destination is not None


def _first_step_bearing_deg(corners: np.ndarray) -> float:
    """Compass bearing (degrees) from the first view's centre to the second's."""
    (lat0, lng0), (lat1, lng1) = view_centre(corners[:2])
    return float(np.degrees(np.arctan2(lng1 - lng0, lat1 - lat0)) % 360.0)


def test_a_trajectory_s_start_heading_says_nothing_of_its_route(splits) -> None:
    """Round 1 starts facing a direction of its own (it faced along the route: the first
    step was straight ahead in every record); later rounds start as the last one ended."""
    off = []
    for loaded in splits.values():
        for rounds in loaded.trajectories().values():
            first = rounds[0]
            turn = first.start_heading_deg - _first_step_bearing_deg(first.gt_path_corners)
            off.append(abs((turn + 180.0) % 360.0 - 180.0))
            for r in rounds[1:]:
                assert (
                    r.start_heading_deg
                    == round(float(view_heading_deg(r.gt_path_corners[0]))) % 360
                )
    # Uniform headings put about 2 in 9 within 20 degrees of the first step; along the
    # route, all of them were.
    assert len(off) >= 40
    assert np.mean(np.asarray(off) <= 20.0) < 0.5
    assert np.median(off) > 45.0


def test_worlds_load_with_layers_on_the_resized_grid(sample_dir: Path, splits) -> None:
    record = splits["val_seen"].records[0]
    world = load_world(sample_dir, record.map_name, record.georef)
    assert world.has_layers
    assert world.bgr.shape[:2] == world.semantic.shape
    native = sample_dir / "train_images" / f"{record.map_name}.tif"
    import cv2

    width = cv2.imread(str(native)).shape[1]
    assert width < world.bgr.shape[1]  # the TIFF is stored at native width, resized on load
    assert world.landmarks and world.metres_per_pixel == pytest.approx(0.4)
    destination = record.destination
    assert destination is not None
    px = record.georef.gps_to_pixel(destination.mean(axis=0))
    assert world.instance[px[1], px[0]] != 0  # the destination is a landmark on the map


TINY_SPEC = DatasetSpec(
    "tiny",
    seed=5,
    map_id_base=500,
    tile_m=550.0,  # small, for speed (at 450 m seed 5 cannot plan every route)
    metres_per_px=0.5,
    seen_maps=1,
    val_unseen_maps=1,
    test_unseen_maps=1,
    records={"train": 4, "val_seen": 2, "val_unseen": 3, "test_unseen": 2},
)


def test_generation_is_byte_identical(tmp_path: Path) -> None:
    spec = TINY_SPEC
    first = build_dataset(spec, tmp_path / "a")
    second = build_dataset(spec, tmp_path / "b")
    assert first["files"] == second["files"]
    assert first["records"] == {"train": 4, "val_seen": 2, "val_unseen": 3, "test_unseen": 2}
    for name in first["files"]:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_sample_out_writes_the_dataset_into_that_folder(
    tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `sample --out DIR` makes DIR the dataset (annotations/ in it), not a versioned
    # folder inside it, and prints DIR; the cache keeps its versioned folders.
    import skyvln_eval.worlds.sample as sample

    monkeypatch.setitem(sample.SPECS, "sample", TINY_SPEC)
    out = tmp_path / "data"
    outcome = cli("sample", "--out", str(out))
    assert outcome.code == 0, outcome
    assert outcome.out.strip() == str(out)
    assert (out / "annotations" / "val_seen_data.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]  # no staging left
    built = (out / "DATASET_INFO.json").stat().st_mtime_ns
    assert cli("sample", "--out", str(out)).code == 0  # there already: kept as it is
    assert (out / "DATASET_INFO.json").stat().st_mtime_ns == built
    # Another dataset there is replaced only with --force; other files never.
    monkeypatch.setitem(sample.SPECS, "sample", replace(TINY_SPEC, seed=6))
    outcome = cli("sample", "--out", str(out))
    assert outcome.code == 2 and "holds another synthetic dataset" in outcome.err
    assert "--force replaces it" in outcome.err
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    outcome = cli("sample", "--out", str(mine), "--force")
    assert outcome.code == 2 and "a folder that is not empty" in outcome.err
    assert (mine / "notes.txt").read_text() == "keep me"
