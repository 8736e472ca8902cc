"""Routes for synthetic trajectories: along streets from a start intersection to a landmark.

A route is a polyline in plan metres. It follows the shortest street path to the
intersection nearest the destination landmark, then flies straight to the landmark's
centre, and is cut into dialog rounds at stop points (snapped to intersections).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from numpy.typing import NDArray

from skyvln_eval.worlds.city.plan import CityPlan, LandmarkSpec

DESTINATION_CATEGORIES = (
    "restaurant",
    "church",
    "stadium",
    "gas_station",
    "roundabout",
    "bridge",
    "park",
    "school",
    "hospital",
    "mall",
    "hotel",
    "tower",
    "water_tower",
)


@dataclass(frozen=True)
class Route:
    """A planned trajectory: polyline, destination, round ends, intersections on the way."""

    points_m: NDArray[np.float64]
    destination: LandmarkSpec
    stop_s: tuple[float, ...]  # arclength (m) where each round ends; the last is the length
    node_s: tuple[float, ...]  # arclength of every intersection the route passes

    @property
    def length_m(self) -> float:
        return float(shapely.LineString(self.points_m).length)

    def point_at(self, s: float) -> NDArray[np.float64]:
        p = shapely.LineString(self.points_m).interpolate(min(max(s, 0.0), self.length_m))
        return np.array([p.x, p.y])

    def bearing_at(self, s: float, lookahead: float = 15.0) -> float:
        """Compass bearing (degrees, 0 = north) of the route around arclength ``s``."""
        a = self.point_at(s)
        b = self.point_at(s + lookahead)
        if np.allclose(a, b):
            a = self.point_at(s - lookahead)
            b = self.point_at(s)
        return compass_bearing(a, b)


def compass_bearing(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Exact compass bearing from plan point ``a`` to ``b`` (x east, y north)."""
    return math.degrees(math.atan2(b[0] - a[0], b[1] - a[1])) % 360.0


def _margin_ok(xy: NDArray[np.float64], plan: CityPlan, margin: float) -> bool:
    return bool(
        margin <= xy[0] <= plan.width_m - margin and margin <= xy[1] <= plan.height_m - margin
    )


def _edge_points(graph: nx.Graph, a: int, b: int) -> NDArray[np.float64]:
    points = np.asarray(graph.edges[a, b]["points"])
    start = np.asarray(graph.nodes[a]["xy"])
    if np.linalg.norm(points[0] - start) > np.linalg.norm(points[-1] - start):
        points = points[::-1]
    return points


def plan_route(
    rng: np.random.Generator, plan: CityPlan, n_rounds: int, margin_m: float = 150.0
) -> Route | None:
    """A random route of ``n_rounds`` rounds, or None if this draw found none."""
    graph = plan.graph
    candidates = [
        lm
        for lm in plan.landmarks
        if lm.category in DESTINATION_CATEGORIES
        and _margin_ok(lm.polygon.mean(axis=0), plan, margin_m)
    ]
    if not candidates or graph.number_of_nodes() < 4:
        return None
    destination = candidates[int(rng.integers(len(candidates)))]
    centre = destination.polygon.mean(axis=0)
    nodes = list(graph.nodes)
    xy = np.array([graph.nodes[n]["xy"] for n in nodes])
    target = nodes[int(np.argmin(np.linalg.norm(xy - centre, axis=1)))]
    wanted = n_rounds * rng.uniform(110, 200)
    distances = nx.single_source_dijkstra_path_length(graph, target, weight="length_m")
    starts = [
        n
        for n, d in distances.items()
        if 0.7 * wanted <= d <= 1.35 * wanted
        and _margin_ok(np.asarray(graph.nodes[n]["xy"]), plan, margin_m)
    ]
    if not starts:
        return None
    start = starts[int(rng.integers(len(starts)))]
    path = nx.shortest_path(graph, start, target, weight="length_m")
    pieces = [np.asarray([graph.nodes[start]["xy"]])]
    node_s = []
    travelled = 0.0
    for a, b in itertools.pairwise(path):
        pieces.append(_edge_points(graph, a, b)[1:])
        travelled += graph.edges[a, b]["length_m"]
        node_s.append(travelled)
    pieces.append(centre[None, :])
    points = np.concatenate(pieces)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 0.5])
    points = points[keep]
    if not all(_margin_ok(p, plan, margin_m * 0.6) for p in points):
        return None
    length = float(shapely.LineString(points).length)
    stops = []
    for k in range(1, n_rounds):
        s = length * k / n_rounds + rng.uniform(-0.1, 0.1) * length / n_rounds
        near = [t for t in node_s if abs(t - s) < 40]
        stops.append(min(near, key=lambda t: abs(t - s)) if near else s)
    stops = sorted({round(s, 3) for s in stops if 40 < s < length - 40})
    if len(stops) != n_rounds - 1:
        return None
    return Route(points, destination, (*stops, length), tuple(node_s[:-1]))
