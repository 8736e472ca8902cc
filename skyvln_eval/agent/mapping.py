"""From agent actions to what each execution mode executes.

- :func:`to_official_action` (official mode): the AVDN action (waypoint in half view
  edges, altitude in [0, 1]) that :func:`~skyvln_eval.avdn.official_step` applies.
- :func:`to_target_pose` (dynamics mode): the pose ``(x_m, y_m, z_m, yaw_rad)`` in the
  ENU frame that a controller should reach.

The two modes differ where the official step cannot do what a multirotor can:

* The official step always turns the view towards its waypoint before moving, so it
  cannot rotate without moving. A pure :class:`Turn` becomes a tiny waypoint in the new
  direction (:data:`TURN_NUDGE` half edges, a few centimetres); the turn is rounded to
  whole degrees as every official turn is.
* It cannot fly sideways either: ``move_left`` / ``move_right`` turn the view by 90
  degrees and move along the new heading. In dynamics mode the drone keeps its heading.
* It moves at most one half edge along each view axis (the waypoint is divided by
  ``max(|x|, |y|, 1)``), measured on the view before the zoom: longer moves are shortened
  along the same direction. Dynamics mode flies the whole distance.
* Heights are clipped to 20-200 m (view edges 40-400 m) in both modes.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
from numpy.typing import ArrayLike

from skyvln_eval.agent.actions import (
    MAX_HEIGHT_M,
    MIN_HEIGHT_M,
    Action,
    Climb,
    FlyTo,
    Move,
    Stop,
    Turn,
    Waypoint,
)
from skyvln_eval.avdn.constants import ALTITUDE_SPAN_M, METERS_PER_DEGREE, MIN_VIEW_EDGE_M
from skyvln_eval.avdn.geometry import view_axes, view_edge_m
from skyvln_eval.avdn.step import OfficialAction
from skyvln_eval.errors import ActionParseError
from skyvln_eval.frames import ViewPose, wrap_angle_rad

#: Length (half view edges) of the waypoint that carries a pure turn in official mode.
TURN_NUDGE: Final = 1e-3


def _altitude_for_edge(edge_m: float) -> float:
    """Official altitude in [0, 1] giving this view edge (clipped to 40-400 m)."""
    edge = min(max(edge_m, 2.0 * MIN_HEIGHT_M), 2.0 * MAX_HEIGHT_M)
    return (edge - MIN_VIEW_EDGE_M) / ALTITUDE_SPAN_M


def _within_reach(x: float, y: float) -> tuple[float, float]:
    """Shorten a waypoint along its direction as the official step will (max(|x|, |y|) <= 1)."""
    scale = max(abs(x), abs(y), 1.0)
    return x / scale, y / scale


def official_shortfall(
    action: Action, current_view: ArrayLike, official: OfficialAction
) -> str | None:
    """What ``official`` (:func:`to_official_action` of ``action`` from ``current_view``)
    does short of ``action``, said for the agent's feedback, or ``None`` when it does what
    was asked: a move or ``fly_to`` beyond one step's reach (half the view's edge) is
    shortened to it, and a height out of 20-200 m is kept within it. The step's own border
    outcomes are said apart."""
    reach_m = official_reach_m(current_view)
    if isinstance(action, Move | FlyTo):
        asked_m = (
            action.distance_m
            if isinstance(action, Move)
            else math.hypot(action.east_m, action.north_m)
        )
        flown_m = math.hypot(*official.waypoint) * reach_m
        if asked_m > flown_m + 0.5:
            return (
                f"shortened to {flown_m:.0f} m of the {asked_m:.0f} m asked: one step reaches "
                f"half the view's edge ({reach_m:.0f} m)"
            )
    if isinstance(action, Climb | FlyTo):
        # The drone's height is half its view's edge too (a 90 degree camera looking down).
        height_m = reach_m + action.distance_m if isinstance(action, Climb) else action.height_m
        if height_m is not None and not MIN_HEIGHT_M <= height_m <= MAX_HEIGHT_M:
            kept = _clip_height(height_m)
            return (
                f"height kept at {kept:.0f} m, not {height_m:.0f} m: the drone flies at "
                f"{MIN_HEIGHT_M:.0f}-{MAX_HEIGHT_M:.0f} m"
            )
    return None


def official_reach_m(current_view: ArrayLike) -> float:
    """How far one official step can move straight ahead from this view: half its edge, metres."""
    return float(view_edge_m(current_view)) / 2.0


def to_official_action(action: Action, current_view: ArrayLike) -> OfficialAction:
    """The official AVDN action that carries out ``action`` from ``current_view`` (4 x [lat, lng]).

    See the module docstring for what the official step cannot do exactly. Raises
    :class:`ActionParseError` for :class:`Stop`, which ends an episode instead of stepping.
    """
    view = np.asarray(current_view, dtype=np.float64)
    edge_m = float(view_edge_m(view))
    half_m = edge_m / 2.0
    keep_altitude = _altitude_for_edge(edge_m)
    if isinstance(action, Move):
        along = action.distance_m / half_m
        x, y = {"forward": (0.0, along), "left": (-along, 0.0), "right": (along, 0.0)}[
            action.direction
        ]
        return OfficialAction(_within_reach(x, y), keep_altitude)
    if isinstance(action, Turn):
        turn = math.radians(action.degrees)
        waypoint = (TURN_NUDGE * math.sin(turn), TURN_NUDGE * math.cos(turn))
        return OfficialAction(waypoint, keep_altitude)
    if isinstance(action, Climb):
        return OfficialAction((0.0, 0.0), _altitude_for_edge(edge_m + 2.0 * action.distance_m))
    if isinstance(action, FlyTo):
        forward, right = view_axes(view)
        displacement_deg = np.array([action.north_m, action.east_m]) / METERS_PER_DEGREE
        half_deg = half_m / METERS_PER_DEGREE
        x = float(displacement_deg @ right) / half_deg
        y = float(displacement_deg @ forward) / half_deg
        altitude = (
            keep_altitude if action.height_m is None else _altitude_for_edge(2 * action.height_m)
        )
        return OfficialAction(_within_reach(x, y), altitude)
    if isinstance(action, Waypoint):
        return OfficialAction((action.x, action.y), action.altitude)
    if isinstance(action, Stop):
        raise ActionParseError("STOP has no official step: it ends the episode")
    raise ActionParseError(f"not an action of the vocabulary: {action!r}")


def _clip_height(z_m: float) -> float:
    return min(max(z_m, MIN_HEIGHT_M), MAX_HEIGHT_M)


def to_target_pose(action: Action, pose: ViewPose) -> ViewPose:
    """The ENU pose (x_m, y_m, z_m, yaw_rad) a controller should fly to for ``action``.

    Moves keep the heading (a multirotor can fly sideways); ``fly_to`` and the AVDN
    waypoint face their direction of travel, as the official step does; ``stop`` holds
    the current pose.
    """
    x, y, z, yaw = pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad
    if isinstance(action, Move):
        offset = {"forward": 0.0, "left": math.pi / 2.0, "right": -math.pi / 2.0}[action.direction]
        direction = yaw + offset
        d = action.distance_m
        return ViewPose(x + d * math.cos(direction), y + d * math.sin(direction), z, yaw)
    if isinstance(action, Turn):
        return ViewPose(x, y, z, wrap_angle_rad(yaw - math.radians(action.degrees)))
    if isinstance(action, Climb):
        return ViewPose(x, y, _clip_height(z + action.distance_m), yaw)
    if isinstance(action, FlyTo):
        far_enough = math.hypot(action.east_m, action.north_m) > 1e-6
        new_yaw = math.atan2(action.north_m, action.east_m) if far_enough else yaw
        height = z if action.height_m is None else _clip_height(action.height_m)
        return ViewPose(x + action.east_m, y + action.north_m, height, new_yaw)
    if isinstance(action, Waypoint):
        wx, wy = _within_reach(action.x, action.y)
        # Right of an ENU yaw is yaw - 90 degrees; half an edge is the height z.
        east = z * (wy * math.cos(yaw) + wx * math.sin(yaw))
        north = z * (wy * math.sin(yaw) - wx * math.cos(yaw))
        new_yaw = math.atan2(north, east) if math.hypot(wx, wy) > 0 else yaw
        edge = MIN_VIEW_EDGE_M + ALTITUDE_SPAN_M * min(max(action.altitude, 0.0), 1.0)
        return ViewPose(x + east, y + north, edge / 2.0, new_yaw)
    if isinstance(action, Stop):
        return pose
    raise ActionParseError(f"not an action of the vocabulary: {action!r}")
