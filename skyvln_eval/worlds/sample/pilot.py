"""Fly a route with official AVDN actions to make ground-truth views.

Every ground-truth view after the start is the output of :func:`official_step` for an
action a human pilot could have taken: turn towards a point a little further along the
route (whole degrees, as the official step turns), move up to almost half an edge, and
change altitude smoothly. Replaying the ground truth with official actions therefore
lands exactly on the ground-truth end view (hull-IoU 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import ALTITUDE_SPAN_M, METERS_PER_DEGREE, MIN_VIEW_EDGE_M
from skyvln_eval.avdn.geometry import view_centre, view_from_pose, view_heading_deg
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.avdn.step import official_step_detailed
from skyvln_eval.worlds.sample.routes import Route, compass_bearing

#: Version of the flights: 1 started a trajectory facing along its route (the start
#: heading gave its first leg away: the first step was straight ahead in every record);
#: 2 starts it facing a direction of its own stream (:func:`start_heading_deg`). Part of
#: the sample's cache key.
FLIGHT_VERSION: Final = 2

View = NDArray[np.float64]


class PilotFailed(Exception):
    """The route could not be flown inside the map; the caller draws another one."""


@dataclass(frozen=True)
class PlanGeo:
    """Conversion between plan metres (x east, y north from the SW corner) and [lat, lng]."""

    georef: MapGeoref

    @property
    def box_m(self) -> tuple[float, float]:
        (lat0, lng0), (lat1, lng1) = self.georef.gps_botm_left, self.georef.gps_top_right
        return (lng1 - lng0) * METERS_PER_DEGREE, (lat1 - lat0) * METERS_PER_DEGREE

    def to_latlng(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.asarray(xy, dtype=np.float64)
        (lat0, lng0) = self.georef.gps_botm_left
        return np.stack(
            [lat0 + p[..., 1] / METERS_PER_DEGREE, lng0 + p[..., 0] / METERS_PER_DEGREE], axis=-1
        )

    def to_metres(self, latlng: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.asarray(latlng, dtype=np.float64)
        (lat0, lng0) = self.georef.gps_botm_left
        return np.stack(
            [(p[..., 1] - lng0) * METERS_PER_DEGREE, (p[..., 0] - lat0) * METERS_PER_DEGREE],
            axis=-1,
        )

    def max_edge_m(self, xy: NDArray[np.float64]) -> float:
        """Largest view edge that fits inside the map at any heading around ``xy``."""
        width, height = self.box_m
        margin = min(xy[0], width - xy[0], xy[1], height - xy[1])
        return 0.97 * math.sqrt(2.0) * margin


@dataclass(frozen=True)
class FlightPlan:
    """Edges (metres) the pilot aims for: at the start, and at the end of each round."""

    start_edge_m: int
    round_end_edges_m: tuple[int, ...]


def plan_edges(rng: np.random.Generator, n_rounds: int, destination_size_m: float) -> FlightPlan:
    start = int(rng.integers(120, 261))
    ends = [int(rng.integers(90, 201)) for _ in range(n_rounds - 1)]
    final = max(int(rng.integers(60, 141)), min(360, math.ceil(destination_size_m * 1.4)))
    return FlightPlan(start, (*ends, final))


def _edge_now(rng: np.random.Generator, start: float, end: float, fraction: float) -> float:
    return start + (end - start) * fraction + rng.uniform(-8, 8)


def start_heading_deg(seed: int) -> float:
    """A trajectory's start heading (whole degrees, 0 = north, clockwise), from a stream of
    its own: nothing of the route, so an agent learns the way from the words, not from the
    way it faces (the pilot's first step turns if need be). Later rounds start as the one
    before ended, as in AVDN."""
    return float(np.random.default_rng(np.random.SeedSequence([seed, 0x5EED])).integers(360))


def fly_route(
    rng: np.random.Generator,
    route: Route,
    geo: PlanGeo,
    flight: FlightPlan,
    start_heading: float,
) -> list[list[View]]:
    """Fly the route from ``start_heading`` (degrees); returns the views of each round.

    Each round's list starts with the view the previous round ended on. Raises
    :class:`PilotFailed` when a step would leave the map (the official step would cancel it).
    """
    start_xy = route.points_m[0]
    start_edge = min(flight.start_edge_m, int(geo.max_edge_m(start_xy)))
    if start_edge < MIN_VIEW_EDGE_M:
        raise PilotFailed("start too close to the map border")
    view = view_from_pose(geo.to_latlng(start_xy), start_heading, float(start_edge))
    bounds = (geo.georef.gps_botm_left, geo.georef.gps_top_right)
    rounds: list[list[View]] = []
    s = 0.0
    round_start_edge = float(start_edge)
    for r, stop in enumerate(route.stop_s):
        views = [view]
        round_start_s = s
        final_round = r == len(route.stop_s) - 1
        for _ in range(40):
            if stop - s < 3.0:
                break
            centre_xy = geo.to_metres(view_centre(view))
            edge = float(np.linalg.norm(view[0] - view[1])) * METERS_PER_DEGREE
            half = edge / 2.0
            step = min(rng.uniform(35, 75), stop - s, 0.92 * half)
            last_step = stop - s <= step + 1e-9
            target_s = s + step
            target = route.point_at(target_s)
            distance = float(np.linalg.norm(target - centre_xy))
            drifted = distance > 0.98 * half
            if drifted:  # away from the route: hop towards it and count only part of the way
                target = centre_xy + (target - centre_xy) * (0.9 * half / distance)
                distance = 0.9 * half
                last_step = False
            heading_now = round(float(view_heading_deg(view))) % 360
            turn = round(compass_bearing(centre_xy, target) - heading_now) % 360
            fraction = (target_s - round_start_s) / max(stop - round_start_s, 1e-6)
            new_edge = _edge_now(
                rng, round_start_edge, flight.round_end_edges_m[r], min(1.0, fraction)
            )
            if last_step and final_round:
                new_edge = float(flight.round_end_edges_m[r])
            limit = min(geo.max_edge_m(centre_xy), geo.max_edge_m(target))
            new_edge = float(int(np.clip(round(new_edge), MIN_VIEW_EDGE_M, min(400.0, limit))))
            if new_edge < MIN_VIEW_EDGE_M or limit < MIN_VIEW_EDGE_M:
                raise PilotFailed("route runs too close to the map border")
            radius = distance / half
            waypoint = (
                radius * math.sin(math.radians(turn)),
                radius * math.cos(math.radians(turn)),
            )
            altitude = (new_edge - MIN_VIEW_EDGE_M) / ALTITUDE_SPAN_M
            result = official_step_detailed(view, waypoint, altitude, *bounds)
            if result.outcome != "full":
                raise PilotFailed(f"official step was {result.outcome}")
            view = result.corners
            views.append(view)
            s = s + 0.5 * step if drifted else target_s
        else:
            raise PilotFailed("round did not reach its stop")
        end_xy = geo.to_metres(view_centre(view))
        if float(np.linalg.norm(end_xy - route.point_at(stop))) > 3.0:
            raise PilotFailed("round ended away from its stop")
        if len(views) < 2:
            raise PilotFailed("round without movement")
        rounds.append(views)
        round_start_edge = float(np.linalg.norm(view[0] - view[1])) * METERS_PER_DEGREE
    return rounds
