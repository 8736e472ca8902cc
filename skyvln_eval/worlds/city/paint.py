"""Paint a city plan into satellite-like BGR imagery plus semantic, instance and height layers.

Everything is drawn with OpenCV polygons at sub-pixel precision, in the order a camera
sees it from above: ground surfaces, water, roads and markings, cars, cast shadows,
roofs, then tree crowns; texture and sensor noise come last. Every colour pass also
writes the class, the landmark instance and the height of what it draws.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray

from skyvln_eval.worlds.city.plan import BGR, Area, Building, Car, CityPlan, Polygon, Road
from skyvln_eval.worlds.tile import SemanticClass as S

SHIFT = 3  # fractional bits of OpenCV coordinates: 1/8 pixel precision
SUN_SHADOW = np.array([0.42, 0.52])  # shadow offset per metre of height (towards north-east)
MAX_SHADOW_M = 60.0

AREA_STYLE: dict[str, tuple[BGR, S]] = {
    "lawn": ((88, 132, 104), S.GRASS),
    "park": ((66, 128, 80), S.GRASS),
    "plaza": ((168, 172, 176), S.PLAZA),
    "parking": ((84, 86, 88), S.PARKING),
    "field": ((62, 150, 72), S.SPORTS_FIELD),
    "track": ((72, 92, 172), S.SPORTS_FIELD),
    "water": ((118, 96, 58), S.WATER),
    "apron": ((150, 153, 152), S.PLAZA),
    "pool": ((228, 186, 84), S.WATER),
}
ASPHALT: BGR = (78, 79, 82)
WHITE: BGR = (235, 236, 236)
YELLOW: BGR = (50, 190, 225)


class Canvas:
    """The four rasters of a tile and the metres -> pixel mapping."""

    def __init__(self, width_px: int, height_px: int, metres_per_px: float) -> None:
        self.mpp = metres_per_px
        self.height_px = height_px
        self.bgr = np.empty((height_px, width_px, 3), np.uint8)
        self.bgr[:] = (118, 136, 142)  # bare ground
        self.semantic = np.zeros((height_px, width_px), np.uint8)
        self.instance = np.zeros((height_px, width_px), np.uint16)
        self.height = np.zeros((height_px, width_px), np.float32)

    def px(self, points_m: Polygon) -> NDArray[np.int32]:
        p = np.asarray(points_m, dtype=np.float64)
        xy = np.empty((len(p), 2))
        np.divide(p[:, 0], self.mpp, out=xy[:, 0])
        np.subtract(self.height_px, p[:, 1] / self.mpp, out=xy[:, 1])
        xy *= 1 << SHIFT
        return np.round(xy).astype(np.int32)

    def fill(
        self,
        polygon: Polygon,
        colour: BGR | None,
        semantic: S | None = None,
        instance: int = 0,
        height: float | None = None,
    ) -> None:
        pts = [self.px(polygon)]
        if colour is not None:
            cv2.fillPoly(self.bgr, pts, colour, cv2.LINE_8, SHIFT)
        if semantic is not None:
            cv2.fillPoly(self.semantic, pts, int(semantic), cv2.LINE_8, SHIFT)
            cv2.fillPoly(self.instance, pts, int(instance), cv2.LINE_8, SHIFT)
        if height is not None:
            cv2.fillPoly(self.height, pts, float(height), cv2.LINE_8, SHIFT)

    def stroke(
        self,
        points: Polygon,
        width_m: float,
        colour: BGR | None,
        semantic: S | None = None,
        closed: bool = False,
    ) -> None:
        pts = [self.px(points)]
        thickness = max(1, round(width_m / self.mpp))
        if colour is not None:
            cv2.polylines(self.bgr, pts, closed, colour, thickness, cv2.LINE_8, SHIFT)
        if semantic is not None:
            cv2.polylines(self.semantic, pts, closed, int(semantic), thickness, cv2.LINE_8, SHIFT)
            cv2.polylines(self.instance, pts, closed, 0, thickness, cv2.LINE_8, SHIFT)
            cv2.polylines(self.height, pts, closed, 0.0, thickness, cv2.LINE_8, SHIFT)


def _scaled(colour: BGR, factor: float) -> BGR:
    return tuple(int(min(255, max(0, c * factor))) for c in colour)  # type: ignore[return-value]


def _dashes(points: Polygon, dash_m: float, gap_m: float, offset_m: float = 0.0) -> list[Polygon]:
    line = shapely.LineString(points)
    if offset_m:
        line = line.offset_curve(offset_m)
        if line.is_empty or line.geom_type != "LineString":
            return []
    out = []
    s = gap_m / 2
    while s + dash_m < line.length:
        a, b = line.interpolate(s), line.interpolate(s + dash_m)
        out.append(np.array([[a.x, a.y], [b.x, b.y]]))
        s += dash_m + gap_m
    return out


def _paint_road(canvas: Canvas, road: Road, rng: np.random.Generator) -> None:
    shade = _scaled(ASPHALT, rng.uniform(0.9, 1.12))
    canvas.stroke(road.points, road.width_m, shade, S.ROAD)
    if road.kind == "boulevard":
        canvas.stroke(road.points, 3.0, (70, 120, 84), S.GRASS)
        for lane in (-1, 1):
            for dash in _dashes(road.points, 3.0, 6.0, lane * road.width_m / 4):
                canvas.stroke(dash, 0.25, WHITE)
    elif road.kind == "avenue":
        for offset in (-0.35, 0.35):  # double yellow centre line
            line = shapely.LineString(road.points).offset_curve(offset)
            if line.geom_type == "LineString":
                canvas.stroke(np.asarray(line.coords), 0.25, YELLOW)
        for side in (-1, 1):
            for dash in _dashes(road.points, 3.0, 6.0, side * road.width_m / 4):
                canvas.stroke(dash, 0.25, WHITE)
    else:
        for dash in _dashes(road.points, 3.0, 5.0):
            canvas.stroke(dash, 0.25, WHITE)


def _paint_area(canvas: Canvas, area: Area, rng: np.random.Generator) -> None:
    colour, semantic = AREA_STYLE[area.kind]
    colour = _scaled(colour, rng.uniform(0.93, 1.07))
    canvas.fill(area.polygon, colour, semantic, area.landmark_id, 0.0)
    if area.kind == "parking" and area.stall_axis is not None:
        _paint_stalls(canvas, area)
    elif area.kind == "field":
        _paint_field_lines(canvas, area.polygon)


def _paint_stalls(canvas: Canvas, area: Area) -> None:
    poly = shapely.Polygon(area.polygon)
    axis = np.asarray(area.stall_axis)
    normal = np.array([-axis[1], axis[0]])
    coords = np.asarray(area.polygon)
    u = coords @ axis
    v = coords @ normal
    rows = np.arange(v.min() + 5.5, v.max(), 17.0)
    for row in rows:
        for k in np.arange(u.min(), u.max(), 2.6):
            a = axis * k + normal * (row - 5.5)
            b = axis * k + normal * (row + 5.5)
            seg = shapely.LineString([a, b]).intersection(poly)
            if seg.geom_type == "LineString" and not seg.is_empty:
                canvas.stroke(np.asarray(seg.coords), 0.15, (200, 202, 204))


def _paint_field_lines(canvas: Canvas, polygon: Polygon) -> None:
    canvas.stroke(np.asarray(polygon), 0.3, WHITE, closed=True)
    p = np.asarray(polygon)
    if len(p) == 4:
        mid_a, mid_b = (p[0] + p[3]) / 2, (p[1] + p[2]) / 2
        centre = (mid_a + mid_b) / 2
        canvas.stroke(np.array([(p[0] + p[1]) / 2, (p[2] + p[3]) / 2]), 0.3, WHITE)
        circle = np.asarray(shapely.Point(centre).buffer(7, 12).exterior.coords)
        canvas.stroke(circle, 0.3, WHITE, closed=True)


def _car_polygon(car: Car, length: float = 4.6, width: float = 1.9) -> Polygon:
    c, s = math.cos(car.heading_rad), math.sin(car.heading_rad)
    along, across = np.array([c, s]) * length / 2, np.array([-s, c]) * width / 2
    centre = np.array([car.x, car.y])
    return np.stack(
        [
            centre + along + across,
            centre + along - across,
            centre - along - across,
            centre - along + across,
        ]
    )


def _paint_car(canvas: Canvas, car: Car) -> None:
    body = _car_polygon(car)
    canvas.fill(body, car.colour, S.VEHICLE, 0, 1.5)
    glass = _car_polygon(
        Car(
            car.x + 0.6 * math.cos(car.heading_rad),
            car.y + 0.6 * math.sin(car.heading_rad),
            car.heading_rad,
            car.colour,
        ),
        1.1,
        1.6,
    )
    canvas.fill(glass, (40, 38, 36))


def _shadow_polygon(footprint: Polygon, height_m: float) -> Polygon:
    offset = SUN_SHADOW * min(height_m, MAX_SHADOW_M / float(np.linalg.norm(SUN_SHADOW)))
    hull = shapely.MultiPoint(np.concatenate([footprint, footprint + offset])).convex_hull
    return np.asarray(hull.exterior.coords)[:-1] if hull.geom_type == "Polygon" else footprint


def _roof_faces(b: Building) -> list[tuple[Polygon, float]]:
    """Roof faces with a brightness factor, sunlit faces (south-west) brighter."""
    p = np.asarray(b.footprint)
    if b.roof in ("flat", "dome") or len(p) != 4 or b.ridge_axis is None:
        return [(p, 1.0)]
    axis = np.asarray(b.ridge_axis)
    # Orient so that p0->p1 runs along the ridge.
    if abs(np.dot(p[1] - p[0], axis)) < abs(np.dot(p[3] - p[0], axis)):
        p = p[[1, 2, 3, 0]]
    m03, m12 = (p[0] + p[3]) / 2, (p[1] + p[2]) / 2
    side_a, side_b = np.array([p[0], p[1], m12, m03]), np.array([m03, m12, p[2], p[3]])
    lit_a = float(np.dot((p[0] + p[1]) / 2 - (p[2] + p[3]) / 2, SUN_SHADOW)) < 0
    if b.roof == "gable":
        return [(side_a, 1.05 if lit_a else 0.72), (side_b, 0.72 if lit_a else 1.05)]
    inset = min(np.linalg.norm(p[3] - p[0]) / 2, np.linalg.norm(p[1] - p[0]) / 2 - 0.5)
    along = (m12 - m03) / np.linalg.norm(m12 - m03)
    r0, r1 = m03 + along * inset, m12 - along * inset
    return [
        (np.array([p[0], p[1], r1, r0]), 1.05 if lit_a else 0.72),
        (np.array([r0, r1, p[2], p[3]]), 0.72 if lit_a else 1.05),
        (np.array([p[0], r0, p[3]]), 0.88),
        (np.array([p[1], p[2], r1]), 0.82),
    ]


def _paint_building(canvas: Canvas, b: Building, rng: np.random.Generator) -> None:
    canvas.fill(b.footprint, None, S.BUILDING, b.landmark_id, b.height_m)
    if b.roof == "dome":
        centre = np.asarray(b.footprint).mean(axis=0)
        radius = float(np.linalg.norm(np.asarray(b.footprint)[0] - centre))
        for k, f in enumerate(np.linspace(0.7, 1.15, 6)):
            r = radius * (1 - k / 7)
            circle = np.asarray(
                shapely.Point(centre - SUN_SHADOW * k * 0.4).buffer(r, 24).exterior.coords
            )
            canvas.fill(circle, _scaled(b.colour, f))
        return
    for face, factor in _roof_faces(b):
        canvas.fill(face, _scaled(b.colour, factor))
    outline = np.asarray(b.footprint)
    if b.roof == "flat":
        canvas.stroke(outline, 0.8, _scaled(b.colour, 0.72), closed=True)
        area = shapely.Polygon(outline).area
        centre = outline.mean(axis=0)
        extent = math.sqrt(area) * 0.3
        for _ in range(int(min(8, area / 250))):
            dx, dy = rng.uniform(-extent, extent, size=2)
            w, h = rng.uniform(1.5, 4.0, size=2)
            box = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2 + centre + (dx, dy)
            canvas.fill(box, _scaled(b.colour, 1.25))
            canvas.stroke(box, 0.3, _scaled(b.colour, 0.6), closed=True)
    else:
        canvas.stroke(outline, 0.3, _scaled(b.colour, 0.6), closed=True)
    _paint_roof_mark(canvas, b)


def _paint_roof_mark(canvas: Canvas, b: Building) -> None:
    if not b.roof_mark:
        return
    p = np.asarray(b.footprint)
    centre = p.mean(axis=0)
    e1, e2 = p[1] - p[0], p[3] - p[0]
    if b.roof_mark == "stripe":
        canvas.fill(np.array([p[0], p[1], p[1] + e2 * 0.22, p[0] + e2 * 0.22]), b.mark_colour)
        canvas.fill(np.array([p[3], p[2], p[2] - e2 * 0.22, p[3] - e2 * 0.22]), b.mark_colour)
        return
    size = 0.22 * min(np.linalg.norm(e1), np.linalg.norm(e2))
    u, v = e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)
    if b.roof_mark in ("cross", "H"):
        arm, bar = size, size / 3
        for a, c in ((u, v), (v, u)):
            canvas.fill(
                np.array(
                    [
                        centre - a * arm - c * bar,
                        centre + a * arm - c * bar,
                        centre + a * arm + c * bar,
                        centre - a * arm + c * bar,
                    ]
                ),
                b.mark_colour,
            )


def _paint_tree(
    canvas: Canvas, tree: shapely.Point, radius: float, height: float, rng: np.random.Generator
) -> None:
    crown = np.asarray(tree.buffer(radius, 10).exterior.coords)
    base = (
        38 + int(rng.integers(-8, 9)),
        88 + int(rng.integers(-14, 15)),
        48 + int(rng.integers(-8, 9)),
    )
    canvas.fill(crown, base, S.TREE, 0, height)
    highlight = np.asarray(
        shapely.Point(tree.x - radius * 0.25, tree.y - radius * 0.25)
        .buffer(radius * 0.55, 8)
        .exterior.coords
    )
    canvas.fill(highlight, _scaled(base, 1.3))


def _add_texture(canvas: Canvas, rng: np.random.Generator) -> None:
    h, w = canvas.semantic.shape
    coarse = rng.normal(0.0, 1.0, size=(h // 16 + 2, w // 16 + 2)).astype(np.float32)
    low = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    # Per-class lookups instead of per-pixel arithmetic on a 0/1 vegetation mask: the
    # same float32 values (computed on the two mask values), a fraction of the work.
    is_vegetation = np.zeros(256, np.float32)
    is_vegetation[[S.GRASS, S.TREE, S.GROUND]] = 1.0
    amplitude = (0.035 + 0.05 * is_vegetation)[canvas.semantic]
    grain_scale = (1.0 + is_vegetation)[canvas.semantic]
    gain = 1.0 + low * amplitude
    noise = rng.integers(-7, 8, size=(h, w, 1), dtype=np.int16)
    # Mixed-type ufuncs compute in float32 directly (uint8 and int16 are exact there).
    grain = np.multiply(noise, grain_scale[..., None], dtype=np.float32)
    out = np.multiply(canvas.bgr, gain[..., None], dtype=np.float32)
    out += grain
    np.clip(out, 0, 255, out=out)
    blurred = cv2.GaussianBlur(out.astype(np.uint8), (3, 3), 0.6)
    canvas.bgr = np.asarray(blurred, dtype=np.uint8)


def paint_plan(plan: CityPlan, metres_per_px: float, rng: np.random.Generator) -> Canvas:
    """Render a plan into a canvas of ``ceil(size / metres_per_px)`` pixels."""
    canvas = Canvas(
        math.ceil(plan.width_m / metres_per_px),
        math.ceil(plan.height_m / metres_per_px),
        metres_per_px,
    )
    for area in plan.areas:
        _paint_area(canvas, area, rng)
    for fence in plan.fences:
        canvas.stroke(fence, 0.3, (70, 100, 84), closed=True)
    if plan.river is not None:
        canvas.stroke(plan.river.points, plan.river.width_m + 8, (96, 130, 120), S.GRASS)
        canvas.stroke(plan.river.points, plan.river.width_m, AREA_STYLE["water"][0], S.WATER)
    for bridge in plan.bridges:
        canvas.fill(bridge.polygon, (132, 134, 138))
    for road in plan.roads:
        _paint_road(canvas, road, rng)
    for x, y, radius, landmark_id in plan.roundabouts:
        ring = np.asarray(shapely.Point(x, y).buffer(radius, 32).exterior.coords)
        island = np.asarray(shapely.Point(x, y).buffer(radius - 10, 32).exterior.coords)
        canvas.fill(ring, ASPHALT, S.ROAD, landmark_id, 0.0)
        canvas.stroke(
            np.asarray(shapely.Point(x, y).buffer(radius - 5, 32).exterior.coords),
            0.25,
            WHITE,
            closed=True,
        )
        canvas.fill(island, (70, 132, 84), S.GRASS, landmark_id, 0.0)
    for bridge in plan.bridges:
        canvas.fill(bridge.polygon, None, S.BRIDGE, bridge.landmark_id, 8.0)
        canvas.stroke(np.asarray(bridge.polygon), 0.6, (60, 62, 66), closed=True)
    for car in plan.cars:
        _paint_car(canvas, car)

    shadow = np.zeros(canvas.semantic.shape, np.uint8)
    for building in plan.buildings:
        cv2.fillPoly(
            shadow,
            [canvas.px(_shadow_polygon(building.footprint, building.height_m))],
            1,
            cv2.LINE_8,
            SHIFT,
        )
    for tree in plan.trees:
        centre = np.array([tree.x, tree.y]) + SUN_SHADOW * tree.height_m * 0.5
        disk = np.asarray(shapely.Point(centre).buffer(tree.radius_m, 10).exterior.coords)
        cv2.fillPoly(shadow, [canvas.px(disk)], 1, cv2.LINE_8, SHIFT)
    mask = shadow.astype(bool)
    canvas.bgr[mask] = (canvas.bgr[mask].astype(np.uint16) * 9 // 16).astype(np.uint8)

    for building in plan.buildings:
        _paint_building(canvas, building, rng)
    for area in plan.areas_top:
        _paint_area(canvas, area, rng)
    for tree in plan.trees:
        _paint_tree(canvas, shapely.Point(tree.x, tree.y), tree.radius_m, tree.height_m, rng)
    _add_texture(canvas, rng)
    return canvas
