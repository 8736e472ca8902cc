"""Actions to the official step (official mode) and to target poses (dynamics mode)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.agent import (
    TURN_NUDGE,
    Climb,
    FlyTo,
    Move,
    Stop,
    Turn,
    Waypoint,
    to_official_action,
    to_target_pose,
)
from skyvln_eval.avdn import MapGeoref, official_step, view_edge_m, view_from_pose
from skyvln_eval.errors import ActionParseError
from skyvln_eval.frames import ViewPose, latlng_to_enu, view_to_pose

GEOREF = MapGeoref((30.0, 40.0), (30.02, 40.02), 1e-5, 1e-5)
BOUNDS = (GEOREF.gps_botm_left, GEOREF.gps_top_right)
START = view_from_pose([30.01, 40.01], 60.0, 120.0)  # heading 60, edge 120 m


def step(action: object) -> tuple[ViewPose, int, np.ndarray]:
    official = to_official_action(action, START)  # type: ignore[arg-type]
    view, heading = official_step(START, official.waypoint, official.altitude, *BOUNDS)
    return view_to_pose(view, GEOREF), heading, view


def start_pose() -> ViewPose:
    return view_to_pose(START, GEOREF)


def moved(a: ViewPose, b: ViewPose) -> tuple[float, float]:
    return b.x_m - a.x_m, b.y_m - a.y_m


def test_move_forward_within_reach_moves_that_far_along_the_heading() -> None:
    pose, heading, _ = step(Move("forward", 40.0))
    east, north = moved(start_pose(), pose)
    assert heading == 60
    assert math.hypot(east, north) == pytest.approx(40.0, abs=0.01)
    assert math.degrees(math.atan2(east, north)) == pytest.approx(60.0, abs=0.1)


def test_a_move_beyond_one_step_is_shortened_to_half_an_edge() -> None:
    pose, _, _ = step(Move("forward", 300.0))
    assert math.hypot(*moved(start_pose(), pose)) == pytest.approx(60.0, abs=0.01)


def test_sideways_moves_turn_the_view_in_official_mode_only() -> None:
    pose, heading, _ = step(Move("left", 30.0))
    east, north = moved(start_pose(), pose)
    assert heading == 330 and math.hypot(east, north) == pytest.approx(30.0, abs=0.01)
    target = to_target_pose(Move("left", 30.0), start_pose())
    assert target.yaw_rad == pytest.approx(start_pose().yaw_rad)  # a multirotor strafes
    assert (target.x_m - start_pose().x_m, target.y_m - start_pose().y_m) == pytest.approx(
        (east, north), abs=0.05
    )


def test_a_pure_turn_is_a_tiny_waypoint_in_the_new_direction() -> None:
    pose, heading, _ = step(Turn(-45.0))
    assert heading == 15
    assert math.hypot(*moved(start_pose(), pose)) == pytest.approx(TURN_NUDGE * 60.0, abs=1e-3)
    target = to_target_pose(Turn(-45.0), start_pose())
    assert target.heading_deg == pytest.approx(15.0, abs=0.05)  # official heading: 1.57 for pi/2
    assert (target.x_m, target.y_m) == (start_pose().x_m, start_pose().y_m)


def test_climbing_changes_the_view_edge_by_twice_the_height() -> None:
    _, heading, view = step(Climb(25.0))
    assert heading == 60 and float(view_edge_m(view)) == pytest.approx(170.0, abs=0.01)
    assert to_target_pose(Climb(25.0), start_pose()).z_m == pytest.approx(85.0)
    assert to_target_pose(Climb(500.0), start_pose()).z_m == 200.0  # clipped to 200 m
    _, _, low = step(Climb(-100.0))
    assert float(view_edge_m(low)) == pytest.approx(40.0, abs=0.01)


def test_fly_to_lands_on_the_landmark_in_both_modes() -> None:
    action = FlyTo("L1", east_m=-20.0, north_m=35.0, height_m=45.0)
    pose, _, view = step(action)
    east, north = moved(start_pose(), pose)
    # The official turn is rounded to whole degrees: at 40 m that is at most 0.35 m off.
    assert (east, north) == pytest.approx((-20.0, 35.0), abs=0.4)
    assert float(view_edge_m(view)) == pytest.approx(90.0, abs=0.01)
    target = to_target_pose(action, start_pose())
    assert (target.x_m - start_pose().x_m, target.y_m - start_pose().y_m) == pytest.approx(
        (-20.0, 35.0)
    )
    assert target.z_m == 45.0 and target.heading_deg == pytest.approx(
        math.degrees(math.atan2(-20, 35)) % 360
    )


def test_the_avdn_waypoint_goes_to_the_same_place_in_both_modes() -> None:
    action = Waypoint(0.4, 0.7, 0.3)
    pose, _, _ = step(action)
    target = to_target_pose(action, start_pose())
    assert (target.x_m, target.y_m) == pytest.approx((pose.x_m, pose.y_m), abs=0.5)
    assert target.edge_m == pytest.approx(40 + 360 * 0.3)
    assert target.heading_deg == pytest.approx(pose.heading_deg, abs=1.0)
    centre = latlng_to_enu(np.mean(START, axis=0), GEOREF)
    assert math.hypot(target.x_m - centre[0], target.y_m - centre[1]) > 10.0


def test_stop_holds_in_dynamics_mode_and_has_no_official_step() -> None:
    assert to_target_pose(Stop(), start_pose()) == start_pose()
    with pytest.raises(ActionParseError, match="ends the episode"):
        to_official_action(Stop(), START)
