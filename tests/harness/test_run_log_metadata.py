"""A run log's episode metadata describes the log written, not the converter's defaults."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyvln_eval.agent.actions import Turn
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import read_log
from skyvln_eval.harness import run_log
from skyvln_eval.harness.run_log import RunLogContent, Step
from skyvln_eval.worlds import WorldTile
from tests.toy_worlds import town_episode, town_world

KEYS = ("observations", "map_tile_max_side_px", "clock_step_ns")


def _write(
    path: Path, world: WorldTile | None, observations: bool, clock_step_ns: int | None
) -> tuple[dict[str, str | None], set[str]]:
    episode = town_episode("fly to the red restaurant")
    start = np.asarray(episode.gt_path_corners[0], dtype=np.float64)
    steps = [Step(0.0, 0, start, "", Turn(90.0), None, {})]
    content = RunLogContent(steps, [start], [0.0], clock_step_ns=clock_step_ns)
    run_log.write_run_log(path, episode, world, content, observations)
    log = read_log(path)
    meta = log.metadata[t.EPISODE_METADATA]
    return {k: meta.get(k) for k in KEYS}, set(log.summary().topic_counts)


def test_a_run_log_without_images_says_so(tmp_path: Path) -> None:
    # observations_in_logs: false wrote no tile and no image, and the metadata said
    # observations=true, map_tile_max_side_px=384 (the converter's defaults).
    meta, topics = _write(tmp_path / "a.mcap", town_world(), False, 1_000_000_000)
    assert not topics & {t.TOPIC_MAP_TILE, t.TOPIC_OBSERVATION, t.TOPIC_CAMERA_VIEWS}
    assert meta == {
        "observations": "false",
        "map_tile_max_side_px": "0",
        "clock_step_ns": "1000000000",
    }


def test_a_run_log_with_images_and_its_own_clock(tmp_path: Path) -> None:
    # A dynamics run has no fixed step: the converter's one view a second was claimed.
    meta, topics = _write(tmp_path / "b.mcap", town_world(), True, None)
    assert {t.TOPIC_MAP_TILE, t.TOPIC_OBSERVATION} <= topics
    assert meta == {"observations": "true", "map_tile_max_side_px": "384", "clock_step_ns": None}
    # Images asked for, but no world to render them from: none written, none claimed.
    meta, topics = _write(tmp_path / "c.mcap", None, True, None)
    assert not topics & {t.TOPIC_MAP_TILE, t.TOPIC_OBSERVATION, t.TOPIC_CAMERA_VIEWS}
    assert meta["observations"] == "false" and meta["map_tile_max_side_px"] == "0"
