"""Lay out a synthetic city: street grid, river and bridges, a boulevard, a roundabout,
then the blocks with their landmarks. Deterministic for a given random generator.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np
import shapely

from skyvln_eval.worlds.city import names
from skyvln_eval.worlds.city.blocks import CAR_COLOURS, Block, BlockFiller
from skyvln_eval.worlds.city.plan import (
    Area,
    Car,
    CityPlan,
    GridFrame,
    Road,
    Tree,
    build_road_graph,
    clip_polyline,
)

SIDEWALK_M = 3.5
LANDMARK_MARGIN_M = 25.0


def _street_lines(rng: np.random.Generator, reach: float) -> list[tuple[float, float, str]]:
    """Positions, widths and kinds of one family of parallel streets."""
    lines = []
    pos = -reach + rng.uniform(0, 80)
    index = 0
    avenue_phase = int(rng.integers(3))
    while pos < reach:
        avenue = index % 3 == avenue_phase
        width = rng.uniform(18, 24) if avenue else rng.uniform(10, 13)
        lines.append((float(pos), float(width), "avenue" if avenue else "street"))
        pos += rng.uniform(115, 185)
        index += 1
    return lines


def _pick(rng: np.random.Generator, pool: tuple[str, ...], used: set[str]) -> str:
    free = [n for n in pool if n not in used] or list(pool)
    name = str(free[int(rng.integers(len(free)))])
    used.add(name)
    return name


def _river(rng: np.random.Generator, plan: CityPlan, frame: GridFrame, reach: float) -> None:
    direction = frame.theta + (math.pi / 2 if rng.random() < 0.5 else 0.0) + rng.uniform(-0.3, 0.3)
    along = np.array([math.cos(direction), math.sin(direction)])
    across = np.array([-along[1], along[0]])
    centre = (
        np.array([plan.width_m / 2, plan.height_m / 2])
        + across * rng.uniform(-0.3, 0.3) * plan.width_m
    )
    s = np.linspace(-reach, reach, 60)
    wave = rng.uniform(20, 50) * np.sin(
        2 * math.pi * s / rng.uniform(400, 800) + rng.uniform(0, 6.3)
    )
    points = centre + s[:, None] * along + wave[:, None] * across
    clipped = clip_polyline(points, plan.width_m, plan.height_m)
    if clipped is not None:
        plan.river = Road(clipped, float(rng.uniform(40, 65)), "street", "river")


def _boulevard(rng: np.random.Generator, plan: CityPlan, name: str) -> None:
    centre = np.array([plan.width_m / 2, plan.height_m / 2])
    a = rng.uniform(0, 2 * math.pi)
    distance = rng.uniform(450, 750)
    pivot = centre + distance * np.array([math.cos(a), math.sin(a)])
    radius = distance - rng.uniform(120, 260)
    t = np.linspace(a + math.pi - 1.1, a + math.pi + 1.1, 90)
    points = pivot + radius * np.stack([np.cos(t), np.sin(t)], axis=1)
    clipped = clip_polyline(points, plan.width_m, plan.height_m)
    if clipped is not None:
        plan.roads.append(Road(clipped, 17.0, "boulevard", name))


def _roundabout(rng: np.random.Generator, plan: CityPlan, avoid: object, used: set[str]) -> None:
    candidates = []
    for node, data in plan.graph.nodes(data=True):
        x, y = data["xy"]
        inner = 120 < x < plan.width_m - 120 and 120 < y < plan.height_m - 120
        if (
            plan.graph.degree(node) >= 4
            and inner
            and not shapely.intersects(shapely.Point(x, y).buffer(60), avoid)
        ):
            candidates.append((x, y))
    if not candidates:
        return
    x, y = candidates[int(rng.integers(len(candidates)))]
    radius = 24.0
    circle = np.asarray(shapely.Point(x, y).buffer(radius, 16).exterior.coords)[:-1]
    lid = plan.add_landmark(
        _pick(rng, names.ROUNDABOUTS, used),
        "roundabout",
        "a roundabout with a grassy island in the middle",
        circle,
        0.0,
    )
    plan.roundabouts.append((x, y, radius, lid))
    plan.trees.append(Tree(x, y, 4.0, 8.0))


def _road_cars(rng: np.random.Generator, plan: CityPlan) -> None:
    """Cars driving on the right of every street, away from intersections."""
    for _, _, edge in plan.graph.edges(data=True):
        points, length = edge["points"], edge["length_m"]
        if length < 40:
            continue
        density = 3.0 if edge["kind"] != "street" else 1.5
        line = shapely.LineString(points)
        for s in rng.uniform(15, length - 15, size=rng.poisson(length / 100 * density)):
            a, b = line.interpolate(s - 1.0), line.interpolate(s + 1.0)
            heading = math.atan2(b.y - a.y, b.x - a.x)
            side = 1.0 if rng.random() < 0.5 else -1.0
            offset = side * edge["width_m"] / 4
            p = line.interpolate(s)
            x = p.x + offset * math.sin(heading)
            y = p.y - offset * math.cos(heading)
            colour = CAR_COLOURS[int(rng.integers(len(CAR_COLOURS)))]
            plan.cars.append(Car(x, y, heading if side > 0 else heading + math.pi, colour))


def _bridges(rng: np.random.Generator, plan: CityPlan, used: set[str]) -> None:
    if plan.river is None:
        return
    water = shapely.LineString(plan.river.points).buffer(plan.river.width_m / 2 + 6)
    named = 0
    for road in plan.roads:
        deck = (
            shapely.LineString(road.points)
            .buffer(road.width_m / 2 + 2, cap_style="flat")
            .intersection(water)
        )
        for part in getattr(deck, "geoms", [deck]):
            if part.is_empty or part.geom_type != "Polygon" or part.area < 50:
                continue
            polygon = np.asarray(part.exterior.coords)[:-1]
            lid = 0
            if named < 2:
                lid = plan.add_landmark(
                    _pick(rng, names.BRIDGES, used),
                    "bridge",
                    f"a bridge that carries {road.name} over the river",
                    polygon,
                    8.0,
                )
                named += 1
            plan.bridges.append(Area(polygon, "plaza", lid))


def plan_city(rng: np.random.Generator, width_m: float, height_m: float) -> CityPlan:
    """Plan a whole tile of ``width_m`` x ``height_m`` metres."""
    plan = CityPlan(width_m, height_m)
    theta = math.radians(rng.uniform(-25, 25)) if rng.random() < 0.8 else 0.0
    frame = GridFrame((width_m / 2, height_m / 2), theta)
    reach = 0.5 * math.hypot(width_m, height_m) + 60
    used: set[str] = set()
    u_lines, v_lines = _street_lines(rng, reach), _street_lines(rng, reach)
    for family, lines in (("u", u_lines), ("v", v_lines)):
        for pos, width, kind in lines:
            ends = [(pos, -reach), (pos, reach)] if family == "u" else [(-reach, pos), (reach, pos)]
            points = clip_polyline(frame.to_world(ends), width_m, height_m)
            if points is not None:
                plan.roads.append(Road(points, width, kind, _pick(rng, names.STREETS, used)))  # type: ignore[arg-type]
    if rng.random() < 0.9:  # most tiles get a river, and with it bridges
        _river(rng, plan, frame, reach)
    if rng.random() < 0.5:
        _boulevard(rng, plan, _pick(rng, names.STREETS, used).replace("Street", "Boulevard"))
    _bridges(rng, plan, used)
    plan.graph = build_road_graph(plan.roads)

    road_shapes = [shapely.LineString(r.points).buffer(r.width_m / 2 + 1.0) for r in plan.roads]
    river_shape = (
        shapely.LineString(plan.river.points).buffer(plan.river.width_m / 2 + 4)
        if plan.river is not None
        else shapely.Polygon()
    )
    curved = [
        shapely.LineString(r.points).buffer(r.width_m / 2 + 1)
        for r in plan.roads
        if r.kind == "boulevard"
    ]
    _roundabout(rng, plan, shapely.union_all([river_shape, *curved]), used)
    disks = [shapely.Point(x, y).buffer(r + 3) for x, y, r, _ in plan.roundabouts]
    keep_out = shapely.union_all([*road_shapes, river_shape, *disks])
    shapely.prepare(keep_out)
    _fill_blocks(rng, plan, frame, u_lines, v_lines, keep_out, river_shape, used)
    _road_cars(rng, plan)
    return plan


def _fill_blocks(
    rng: np.random.Generator,
    plan: CityPlan,
    frame: GridFrame,
    u_lines: list[tuple[float, float, str]],
    v_lines: list[tuple[float, float, str]],
    keep_out: object,
    river_shape: object,
    used: set[str],
) -> None:
    filler = BlockFiller(plan, frame, rng, keep_out)
    tile = shapely.box(0, 0, plan.width_m, plan.height_m)
    inner_tile = shapely.box(
        LANDMARK_MARGIN_M,
        LANDMARK_MARGIN_M,
        plan.width_m - LANDMARK_MARGIN_M,
        plan.height_m - LANDMARK_MARGIN_M,
    )
    blocks: list[Block] = []
    for (ua, wa, _), (ub, wb, _) in itertools.pairwise(u_lines):
        for (va, xa, _), (vb, xb, _) in itertools.pairwise(v_lines):
            block = Block(
                ua + wa / 2 + SIDEWALK_M,
                va + xa / 2 + SIDEWALK_M,
                ub - wb / 2 - SIDEWALK_M,
                vb - xb / 2 - SIDEWALK_M,
            )
            if shapely.intersects(
                shapely.Polygon(filler.rect(block.u0, block.v0, block.u1, block.v1)), tile
            ):
                blocks.append(block)
    for block in blocks:  # sidewalks first; every block's content is drawn over them
        sidewalk = filler.rect(
            block.u0 - SIDEWALK_M,
            block.v0 - SIDEWALK_M,
            block.u1 + SIDEWALK_M,
            block.v1 + SIDEWALK_M,
        )
        plan.areas.append(Area(sidewalk, "plaza"))

    def is_clear(block: Block) -> bool:
        polygon = shapely.Polygon(filler.rect(block.u0, block.v0, block.u1, block.v1))
        return bool(shapely.contains(inner_tile, polygon)) and not shapely.intersects(
            polygon, keep_out
        )

    order = [int(i) for i in rng.permutation(len(blocks))]
    clear = [i for i in order if is_clear(blocks[i])]
    assigned: dict[int, Callable[[Block], None]] = {}

    def take(min_side: float, action: Callable[[Block], None], largest: bool = False) -> None:
        free = [i for i in clear if i not in assigned and blocks[i].min_side >= min_side]
        if not free:
            return
        index = max(free, key=lambda i: blocks[i].width * blocks[i].depth) if largest else free[0]
        assigned[index] = action

    def then_generic(first: Callable[[Block], Block]) -> Callable[[Block], None]:
        return lambda b: (
            filler.commercial(first(b)) if rng.random() < 0.5 else filler.residential(first(b))
        )

    take(100, lambda b: filler.stadium(b, _pick(rng, names.STADIUMS, used)), largest=True)
    if rng.random() < 0.7:
        take(95, lambda b: filler.mall(b, _pick(rng, names.MALLS, used)))
    if rng.random() < 0.7:
        take(85, lambda b: filler.hospital(b, _pick(rng, names.HOSPITALS, used)))
    take(85, lambda b: filler.school(b, _pick(rng, names.SCHOOLS, used)))
    for _ in range(int(rng.integers(1, 3))):
        take(60, lambda b: filler.park(b, _pick(rng, names.PARKS, used)))
    for _ in range(int(rng.integers(1, 3))):
        take(75, then_generic(lambda b: filler.church(b, _pick(rng, names.CHURCHES, used))))
    for _ in range(int(rng.integers(1, 3))):
        take(
            60, then_generic(lambda b: filler.gas_station(b, _pick(rng, names.GAS_STATIONS, used)))
        )
    for _ in range(int(rng.integers(4, 8))):
        take(55, then_generic(lambda b: filler.restaurant(b, _pick(rng, names.RESTAURANTS, used))))
    if rng.random() < 0.7:
        take(65, then_generic(lambda b: filler.hotel(b, _pick(rng, names.HOTELS, used))))
    if rng.random() < 0.6:
        take(55, lambda b: filler.commercial(filler.tower(b, _pick(rng, names.TOWERS, used))))
    if rng.random() < 0.5:

        def homes_with_water_tower(b: Block) -> None:
            filler.residential(b)
            filler.water_tower(b, "Water Tower")

        take(60, homes_with_water_tower)

    centre = np.array([plan.width_m / 2, plan.height_m / 2])
    for index in order:
        block = blocks[index]
        if index in assigned:
            assigned[index](block)
            continue
        polygon = shapely.Polygon(filler.rect(block.u0, block.v0, block.u1, block.v1))
        if shapely.intersects(polygon, river_shape):
            plan.areas.append(Area(np.asarray(polygon.exterior.coords)[:-1], "park"))
            filler.add_trees(block, int(block.width * block.depth / 400))
            continue
        middle = frame.to_world([((block.u0 + block.u1) / 2, (block.v0 + block.v1) / 2)])[0]
        downtown = float(np.linalg.norm(middle - centre)) < 0.25 * plan.width_m
        if (downtown and rng.random() < 0.75) or rng.random() < 0.25:
            filler.commercial(block)
        else:
            filler.residential(block)
