"""The official AVDN step: how an action (waypoint, altitude) moves a view.

An action is a waypoint ``(x, y)`` in the current view frame (x to the right, y forward,
1 = half an edge) and an altitude ``a`` in [0, 1]. The step zooms the view to the target
edge, rotates it about its centre by the waypoint's direction and moves it forward by the
waypoint's length; each stage is cancelled when a corner would leave the open map box.
Reproduces the official rollouts to the micrometre (see tests/avdn/test_official_step.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.constants import (
    ALTITUDE_SPAN_M,
    METERS_PER_DEGREE,
    MIN_VIEW_EDGE_M,
    OFFICIAL_PI,
)
from skyvln_eval.avdn.geometry import view_axes, view_centre, view_edge_m, view_heading_deg

StepOutcome = Literal["full", "cancelled", "zoom_only", "rotate_only"]
LatLng = tuple[float, float]


@dataclass(frozen=True)
class OfficialAction:
    """One official action: waypoint in view units (x right, y forward) and altitude in [0, 1]."""

    waypoint: tuple[float, float]
    altitude: float


@dataclass(frozen=True)
class OfficialStepResult:
    """The view after a step, its stored heading, and which stages took effect."""

    corners: NDArray[np.float64]
    heading_deg: int
    outcome: StepOutcome
    turn_deg: int


def action_turn_deg(waypoint: Sequence[float]) -> int:
    """Clockwise turn of a waypoint, whole degrees, computed as officially.

    ``round(((atan2(x, y) / 3.14159 + 2) / 2 % 1) * 360)``: with 3.14159 for pi this can be
    360 (31 of the 6,729 official test steps are), which rotates by 360 * 3.14159 / 180
    rad, not exactly a full turn; we keep it to reproduce official views to the micrometre.
    The stored heading is taken modulo 360, so it is unaffected.
    """
    x, y = _normalised_waypoint(waypoint)
    fraction = (math.atan2(x, y) / OFFICIAL_PI + 2.0) / 2.0 % 1.0
    return round(fraction * 360.0)


def action_target_edge_m(altitude: float) -> int:
    """Target view edge of an altitude action: ``round(360 * clip(a, 0, 1)) + 40`` metres."""
    return round(min(1.0, max(0.0, float(altitude))) * ALTITUDE_SPAN_M) + int(MIN_VIEW_EDGE_M)


def _normalised_waypoint(waypoint: Sequence[float]) -> tuple[float, float]:
    x, y = float(waypoint[0]), float(waypoint[1])
    scale = max(abs(x), abs(y), 1.0)
    return x / scale, y / scale


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v)


def _zoomed(corners: NDArray[np.float64], change_deg: float) -> NDArray[np.float64]:
    # Each corner moves outwards along both of its edges by the same amount, so the view
    # keeps its centre and heading and its edge grows by 2 * change.
    out = np.empty_like(corners)
    for i in range(4):
        prev_corner, next_corner = corners[(i + 3) % 4], corners[(i + 1) % 4]
        out[i] = (
            corners[i]
            + _unit(corners[i] - next_corner) * change_deg
            + _unit(corners[i] - prev_corner) * change_deg
        )
    return out


def _rotated_clockwise(corners: NDArray[np.float64], turn_deg: int) -> NDArray[np.float64]:
    theta = turn_deg / 180.0 * OFFICIAL_PI
    cos_t, sin_t = math.cos(theta), math.sin(theta)
    centre = corners.mean(axis=0)
    d = corners - centre
    out = np.empty_like(corners)
    # Clockwise on a north-up map, in (lat, lng) components.
    out[:, 0] = centre[0] + cos_t * d[:, 0] - sin_t * d[:, 1]
    out[:, 1] = centre[1] + sin_t * d[:, 0] + cos_t * d[:, 1]
    return out


def _moved_forward(corners: NDArray[np.float64], distance_deg: float) -> NDArray[np.float64]:
    left = _unit(corners[0] - corners[3]) * distance_deg
    right = _unit(corners[1] - corners[2]) * distance_deg
    return corners + np.stack([left, right, right, left])


def _inside(
    corners: NDArray[np.float64], botm_left: Sequence[float], top_right: Sequence[float]
) -> bool:
    lat, lng = corners[:, 0], corners[:, 1]
    return bool(
        np.all(
            (lat > botm_left[0])
            & (lat < top_right[0])
            & (lng > botm_left[1])
            & (lng < top_right[1])
        )
    )


def official_step_variants(
    corners: ArrayLike, waypoint: Sequence[float], altitude: float
) -> dict[StepOutcome, OfficialStepResult]:
    """Every result an official step can have, whatever the map bounds.

    The official step returns one of these four depending on which stage first puts a
    corner outside the map; useful to check rollouts recorded without their map bounds.
    """
    view = np.array(corners, dtype=np.float64).reshape(4, 2)
    x, y = _normalised_waypoint(waypoint)
    turn = action_turn_deg((x, y))
    distance_deg = math.hypot(x, y) * float(np.linalg.norm(view[0] - view[1])) / 2.0
    heading = round(float(view_heading_deg(view))) % 360
    change = 0.5 * (action_target_edge_m(altitude) - float(view_edge_m(view))) / METERS_PER_DEGREE
    zoomed = _zoomed(view, change)
    rotated = _rotated_clockwise(zoomed, turn)
    moved = _moved_forward(rotated, distance_deg)
    new_heading = (heading + turn) % 360
    return {
        "cancelled": OfficialStepResult(view, heading, "cancelled", turn),
        "zoom_only": OfficialStepResult(zoomed, heading, "zoom_only", turn),
        "rotate_only": OfficialStepResult(rotated, new_heading, "rotate_only", turn),
        "full": OfficialStepResult(moved, new_heading, "full", turn),
    }


def official_step_detailed(
    corners: ArrayLike,
    waypoint: Sequence[float],
    altitude: float,
    gps_botm_left: Sequence[float],
    gps_top_right: Sequence[float],
) -> OfficialStepResult:
    """:func:`official_step`, also telling which stages took effect and the turn."""
    variants = official_step_variants(corners, waypoint, altitude)
    for stage, fallback in (
        ("zoom_only", "cancelled"),
        ("rotate_only", "zoom_only"),
        ("full", "rotate_only"),
    ):
        if not _inside(variants[stage].corners, gps_botm_left, gps_top_right):  # type: ignore[index]
            return variants[fallback]  # type: ignore[index]
    return variants["full"]


def official_step(
    corners: ArrayLike,
    waypoint: Sequence[float],
    altitude: float,
    gps_botm_left: Sequence[float],
    gps_top_right: Sequence[float],
) -> tuple[NDArray[np.float64], int]:
    """Apply one official action to a view; returns ``(new_corners, heading_deg)``.

    1. ``(x, y)`` is divided by ``max(|x|, |y|, 1)``; the turn is its clockwise angle in
       whole degrees, the distance its length times half the current edge, and the target
       edge ``round(360 * clip(a, 0, 1)) + 40`` m.
    2. Zoom to the target edge; if a corner leaves the open map box, nothing changes.
    3. Rotate clockwise about the centre; if a corner leaves, the zoomed view is returned
       with the old heading.
    4. Move forward; if a corner leaves, the rotated view is returned with the new heading.

    The heading is ``round(official heading of the input view) % 360`` plus the turn,
    modulo 360, as the official code stores it.
    """
    result = official_step_detailed(corners, waypoint, altitude, gps_botm_left, gps_top_right)
    return result.corners, result.heading_deg


def action_between_views(current: ArrayLike, following: ArrayLike) -> OfficialAction:
    """The official action that takes view ``current`` to view ``following``.

    The waypoint is the displacement of the centre in the current view's frame, in half
    edges, and the altitude gives the following view's edge. Exact when ``following`` was
    reachable by one official step (it moves along its own new heading); otherwise it is
    the action that best approaches it (the centre lands where the official step can put
    it, with the nearest whole-degree turn).

    The waypoint's direction is snapped to the whole-degree turn the official step will
    make of it. This changes nothing for the step except when float noise puts a
    straight-ahead waypoint a hair left of the axis: the official rounding would then
    turn by "360" degrees, which with 3.14159 for pi is not a full turn (0.8 mm off on a
    200 m view).
    """
    cur = np.asarray(current, dtype=np.float64)
    nxt = np.asarray(following, dtype=np.float64)
    forward, right = view_axes(cur)
    half_edge_deg = float(np.linalg.norm(cur[0] - cur[1])) / 2.0
    displacement = view_centre(nxt) - view_centre(cur)
    x = float(displacement @ right) / half_edge_deg
    y = float(displacement @ forward) / half_edge_deg
    x, y = _normalised_waypoint((x, y))
    radius = math.hypot(x, y)
    turn = math.radians(action_turn_deg((x, y)) % 360)
    altitude = (float(view_edge_m(nxt)) - MIN_VIEW_EDGE_M) / ALTITUDE_SPAN_M
    return OfficialAction(
        waypoint=(radius * math.sin(turn), radius * math.cos(turn)), altitude=altitude
    )


def replay_actions(
    start: ArrayLike,
    actions: Sequence[OfficialAction],
    gps_botm_left: Sequence[float],
    gps_top_right: Sequence[float],
) -> list[OfficialStepResult]:
    """Apply actions one after another from ``start``; returns one result per action."""
    view = np.asarray(start, dtype=np.float64)
    results = []
    for action in actions:
        result = official_step_detailed(
            view, action.waypoint, action.altitude, gps_botm_left, gps_top_right
        )
        results.append(result)
        view = result.corners
    return results


def replay_ground_truth(
    gt_path_corners: ArrayLike, gps_botm_left: LatLng, gps_top_right: LatLng
) -> NDArray[np.float64]:
    """Views visited when the ground-truth path is flown with official actions.

    Derives the action between consecutive GT views and applies it with the official
    step from the GT start view; returns the visited views ``(N, 4, 2)``, start included.
    """
    gt = np.asarray(gt_path_corners, dtype=np.float64)
    views = [gt[0]]
    for k in range(len(gt) - 1):
        action = action_between_views(views[-1], gt[k + 1])
        views.append(
            official_step(
                views[-1], action.waypoint, action.altitude, gps_botm_left, gps_top_right
            )[0]
        )
    return np.stack(views)
