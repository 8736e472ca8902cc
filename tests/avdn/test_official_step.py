"""The official step reproduces the official agent's rollouts on AVDN test_unseen."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from skyvln_eval.avdn import (
    DEFAULT_MAX_ACTION_LEN,
    METERS_PER_DEGREE,
    action_target_edge_m,
    action_turn_deg,
    official_step,
    official_step_detailed,
    official_step_variants,
    view_edge_m,
    view_from_pose,
    view_heading_deg,
)
from tests.conftest import FIXTURES, SHARED_FIXTURES

ONE_MM = 1e-3


def _check_rollouts(episodes: list[dict[str, Any]]) -> dict[str, int]:
    """Match every step of every episode; returns counts by outcome (asserting all match)."""
    counts = {"steps": 0, "full": 0, "cancelled": 0, "zoom_only": 0, "rotate_only": 0}
    for episode in episodes:
        views, headings = episode["path_corners"], episode["path_headings"]
        for k in range(len(views) - 1):
            action = episode["actions"][k]
            variants = official_step_variants(views[k], action["waypoint"], action["altitude"])
            target = np.asarray(views[k + 1])
            errors = {
                name: float(np.abs(v.corners - target).max()) * METERS_PER_DEGREE
                for name, v in variants.items()
            }
            name = "full" if errors["full"] < ONE_MM else min(errors, key=errors.__getitem__)
            assert errors[name] < ONE_MM, (episode["instr_id"], k, errors)
            assert variants[name].heading_deg == headings[k + 1], (episode["instr_id"], k)
            counts["steps"] += 1
            counts[name] += 1
    return counts


def test_project_fixture_rollouts_are_reproduced() -> None:
    episodes = json.loads((FIXTURES / "avdn_official_rollouts_subset.json").read_text())
    counts = _check_rollouts(episodes)
    assert counts["steps"] == sum(len(e["path_corners"]) - 1 for e in episodes)
    # The subset was chosen to contain every bounds-cancelled kind.
    assert counts["cancelled"] and counts["zoom_only"] and counts["rotate_only"]
    assert counts["full"] >= 0.8 * counts["steps"]


SHARED_FILE = SHARED_FIXTURES / "avdn_test_unseen_official_rollouts.json"


@pytest.mark.skipif(not SHARED_FILE.is_file(), reason=f"{SHARED_FILE} is not on this machine")
def test_all_official_rollouts_are_reproduced() -> None:
    episodes = json.loads(SHARED_FILE.read_text())
    counts = _check_rollouts(episodes)
    assert len(episodes) == 897
    # Every step of the spec's count, of each kind (an audit counted them independently).
    kinds = {"full": 6649, "cancelled": 53, "zoom_only": 16, "rotate_only": 11}
    assert counts == {"steps": 6729, **kinds}
    for episode in episodes:
        views, progress = episode["path_corners"], episode["progress"]
        where = episode["instr_id"]
        # One action, heading and progress per view, the start included; at most
        # max_action_len (10) views; the start view's heading is its own, rounded.
        assert len(episode["actions"]) == len(episode["path_headings"]) == len(progress)
        assert len(views) == len(progress) <= DEFAULT_MAX_ACTION_LEN, where
        assert np.array_equal(episode["start_view"], views[0]), where
        start_heading = round(float(view_heading_deg(np.asarray(views[0])))) % 360
        assert episode["path_headings"][0] == start_heading, where
        # The official agent stops once its predicted progress exceeds 0.5, or at the cap.
        assert not any(p > 0.5 for p in progress[:-1]), where
        assert progress[-1] > 0.5 or len(views) == DEFAULT_MAX_ACTION_LEN, where


def test_step_inside_map_is_full_and_cancels_at_the_border() -> None:
    view = view_from_pose((30.005, 40.005), 0.0, 100.0)
    big = ((29.0, 39.0), (31.0, 41.0))
    corners, heading = official_step(view, (0.0, 1.0), 60 / 360, *big)
    # Straight ahead by half an edge (50 m), new edge 100 m, heading unchanged.
    moved = (corners.mean(axis=0) - view.mean(axis=0)) * METERS_PER_DEGREE
    assert np.allclose(moved, [50.0, 0.0], atol=1e-6)
    assert view_edge_m(corners) == pytest.approx(100.0)
    assert heading == 0
    # A box that the zoomed view would leave cancels the whole step.
    tight = ((30.005 - 0.0005, 40.005 - 0.0005), (30.005 + 0.0005, 40.005 + 0.0005))
    result = official_step_detailed(view, (0.0, 1.0), 1.0, *tight)
    assert result.outcome == "cancelled"
    assert np.array_equal(result.corners, view)


def test_rotate_only_keeps_new_heading_when_the_move_leaves_the_map() -> None:
    view = view_from_pose((30.005, 40.005), 0.0, 100.0)
    # Box just large enough for the rotated view, not for moving 70 m east.
    half = 100 / 2 * math.sqrt(2) / METERS_PER_DEGREE * 1.01
    box = ((30.005 - half, 40.005 - half), (30.005 + half, 40.005 + half))
    result = official_step_detailed(view, (1.0, 0.0), 60 / 360, *box)
    assert result.outcome == "rotate_only"
    assert result.heading_deg == 90
    assert result.turn_deg == 90


def test_waypoint_is_normalised_and_altitude_clipped() -> None:
    assert action_turn_deg((0.0, 1.0)) == 0
    assert action_turn_deg((1.0, 0.0)) == 90
    assert action_turn_deg((0.0, -5.0)) == 180
    assert action_turn_deg((-1.0, 0.0)) == 270
    assert action_target_edge_m(-3.0) == 40
    assert action_target_edge_m(7.0) == 400
    assert action_target_edge_m(0.5) == 220
    view = view_from_pose((30.005, 40.005), 0.0, 100.0)
    box = ((29.0, 39.0), (31.0, 41.0))
    # (4, 4) is divided by max(|x|, |y|, 1) = 4 -> (1, 1): 45 degrees, sqrt(2) half edges.
    corners, heading = official_step(view, (4.0, 4.0), 60 / 360, *box)
    moved = (corners.mean(axis=0) - view.mean(axis=0)) * METERS_PER_DEGREE
    assert heading == 45
    assert np.linalg.norm(moved) == pytest.approx(50 * math.sqrt(2), abs=1e-3)


def test_official_heading_uses_the_1_57_approximation() -> None:
    view = view_from_pose((30.0, 40.0), 45.0, 100.0)
    # arctan(1) / 1.57 * 90 = 45.0225..., so the official heading is 90 - 45.0225.
    expected = 90.0 - math.atan(1.0) / 1.57 * 90.0
    assert view_heading_deg(view) == pytest.approx(expected, abs=1e-9)
    assert view_heading_deg(view_from_pose((30.0, 40.0), 0.0, 100.0)) == pytest.approx(
        0.0, abs=1e-9
    )
    assert view_heading_deg(view_from_pose((30.0, 40.0), 90.0, 100.0)) == pytest.approx(
        90.0, abs=1e-9
    )
    assert view_heading_deg(view_from_pose((30.0, 40.0), 180.0, 100.0)) == pytest.approx(
        180.0, abs=1e-9
    )
