"""Vector plan of a synthetic city tile, in metres (x east, y north, origin south-west).

The plan is what the painter draws and what routes are planned on: roads (with a
routable networkx graph), a river with bridges, surface areas (parks, parking, fields),
buildings with roof styles and heights, trees, cars, and named landmarks.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Literal

import networkx as nx
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Point
from shapely.ops import substring

Polygon = NDArray[np.float64]  # (n, 2) metres
BGR = tuple[int, int, int]
RoadKind = Literal["avenue", "street", "boulevard"]
RoofStyle = Literal["flat", "gable", "hip", "dome"]
AreaKind = Literal[
    "park", "parking", "plaza", "field", "track", "water", "lawn", "stands", "apron", "pool"
]


@dataclass
class Road:
    points: Polygon
    width_m: float
    kind: RoadKind
    name: str


@dataclass
class Building:
    footprint: Polygon
    roof: RoofStyle
    colour: BGR
    colour_name: str
    height_m: float
    ridge_axis: NDArray[np.float64] | None = None  # unit vector along the ridge
    landmark_id: int = 0
    roof_mark: Literal["", "H", "cross", "stripe"] = ""
    mark_colour: BGR = (255, 255, 255)


@dataclass
class Area:
    polygon: Polygon
    kind: AreaKind
    landmark_id: int = 0
    stall_axis: NDArray[np.float64] | None = None  # parking rows run along this unit vector


@dataclass
class Tree:
    x: float
    y: float
    radius_m: float
    height_m: float


@dataclass
class Car:
    x: float
    y: float
    heading_rad: float  # direction of the car's length, from the x axis
    colour: BGR


@dataclass
class LandmarkSpec:
    landmark_id: int
    name: str
    category: str
    description: str
    polygon: Polygon
    height_m: float


@dataclass
class CityPlan:
    width_m: float
    height_m: float
    roads: list[Road] = field(default_factory=list)
    river: Road | None = None
    bridges: list[Area] = field(default_factory=list)
    roundabouts: list[tuple[float, float, float, int]] = field(default_factory=list)  # x, y, r, id
    areas: list[Area] = field(default_factory=list)
    areas_top: list[Area] = field(default_factory=list)  # drawn over buildings (stadium field)
    buildings: list[Building] = field(default_factory=list)
    trees: list[Tree] = field(default_factory=list)
    fences: list[Polygon] = field(default_factory=list)  # parcel outlines of house lots
    cars: list[Car] = field(default_factory=list)
    landmarks: list[LandmarkSpec] = field(default_factory=list)
    graph: nx.Graph = field(default_factory=nx.Graph)

    def add_landmark(
        self, name: str, category: str, description: str, polygon: Polygon, height_m: float
    ) -> int:
        landmark_id = len(self.landmarks) + 1
        self.landmarks.append(
            LandmarkSpec(landmark_id, name, category, description, np.asarray(polygon), height_m)
        )
        return landmark_id


@dataclass(frozen=True)
class GridFrame:
    """The street grid's frame: u along one street family, v along the other.

    The grid is rotated by ``theta`` about the tile centre, as real cities rarely align
    with north.
    """

    centre: tuple[float, float]
    theta: float

    @property
    def u_axis(self) -> NDArray[np.float64]:
        return np.array([math.cos(self.theta), math.sin(self.theta)])

    @property
    def v_axis(self) -> NDArray[np.float64]:
        return np.array([-math.sin(self.theta), math.cos(self.theta)])

    def to_world(self, uv: NDArray[np.float64] | list[tuple[float, float]]) -> Polygon:
        p = np.asarray(uv, dtype=np.float64)
        return np.asarray(self.centre) + p[..., :1] * self.u_axis + p[..., 1:2] * self.v_axis

    def rect(self, u0: float, v0: float, u1: float, v1: float) -> Polygon:
        return self.to_world([(u0, v0), (u1, v0), (u1, v1), (u0, v1)])


def build_road_graph(roads: list[Road]) -> nx.Graph:
    """A routable graph from road polylines: nodes at ends and crossings, edges as polylines.

    Node keys are integer ids; each node has ``xy`` (metres) and each edge ``points``
    (its polyline, in either direction), ``length_m``, ``road`` (name), ``width_m``, ``kind``.
    """
    lines = [LineString(r.points) for r in roads]
    cuts: list[list[float]] = [[0.0, line.length] for line in lines]
    for i in range(len(lines)):
        for j in range(i + 1, len(lines)):
            hit = lines[i].intersection(lines[j])
            for point in getattr(hit, "geoms", [hit]):
                if isinstance(point, Point) and not point.is_empty:
                    cuts[i].append(lines[i].project(point))
                    cuts[j].append(lines[j].project(point))
    graph = nx.Graph()
    node_of: dict[tuple[int, int], int] = {}

    def node(xy: tuple[float, float]) -> int:
        key = (round(xy[0] * 2), round(xy[1] * 2))  # merge points closer than ~0.5 m
        if key not in node_of:
            node_of[key] = len(node_of)
            graph.add_node(node_of[key], xy=(float(xy[0]), float(xy[1])))
        return node_of[key]

    for road, line, params in zip(roads, lines, cuts, strict=True):
        marks = sorted({round(p, 3) for p in params})
        for a, b in itertools.pairwise(marks):
            if b - a < 1.0:
                continue
            piece = substring(line, a, b)
            coords = np.asarray(piece.coords)
            n0, n1 = node(tuple(coords[0])), node(tuple(coords[-1]))
            if n0 != n1:
                graph.add_edge(
                    n0,
                    n1,
                    points=coords,
                    length_m=float(piece.length),
                    road=road.name,
                    width_m=road.width_m,
                    kind=road.kind,
                )
    return graph


def clip_polyline(points: Polygon, width_m: float, height_m: float) -> Polygon | None:
    """Clip a polyline to the tile box; None when nothing remains."""
    box = shapely.box(0.0, 0.0, width_m, height_m)
    clipped = LineString(points).intersection(box)
    if clipped.is_empty:
        return None
    if clipped.geom_type == "MultiLineString":
        clipped = max(clipped.geoms, key=lambda g: g.length)
    if clipped.geom_type != "LineString" or clipped.length < 5.0:
        return None
    return np.asarray(clipped.coords)
