"""Small hand-made worlds for camera, perception and agent tests (0.5 m pixels, 600 m square)."""

from __future__ import annotations

import numpy as np

from skyvln_eval.avdn import Episode, MapGeoref, parse_record, view_from_pose
from skyvln_eval.worlds.tile import Landmark, SemanticClass, WorldTile

MPP = 0.5
SIZE = 1200


def georef() -> MapGeoref:
    ratio = MPP / 111_300.0
    return MapGeoref((30.0, 40.0), (30.0 + SIZE * ratio, 40.0 + SIZE * ratio), ratio, ratio)


def textured(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 255, size=(SIZE // 20, SIZE // 20, 3), dtype=np.uint8)
    return np.repeat(np.repeat(coarse, 20, axis=0), 20, axis=1)


def rows_cols(x_m: float, y_m: float, half_m: float) -> tuple[slice, slice]:
    """Pixel slices of a square of half side ``half_m`` centred on ENU ``(x_m, y_m)``."""
    col, row, half = round(x_m / MPP), round(SIZE - y_m / MPP), round(half_m / MPP)
    return slice(row - half, row + half), slice(col - half, col + half)


def flat_world() -> WorldTile:
    """An xView-like world: an image and nothing else."""
    return WorldTile("flat", georef(), textured())


def tower_world(height_m: float = 60.0) -> WorldTile:
    """A world with one 40 m square tower (landmark 7) at the map centre."""
    semantic = np.full((SIZE, SIZE), SemanticClass.GROUND, np.uint8)
    instance = np.zeros((SIZE, SIZE), np.uint16)
    heights = np.zeros((SIZE, SIZE), np.float32)
    square = rows_cols(300.0, 300.0, 20.0)
    semantic[square] = SemanticClass.BUILDING
    instance[square] = 7
    heights[square] = height_m
    return WorldTile("tower", georef(), textured(1), semantic, instance, heights)


def _landmark(
    lid: int, category: str, description: str, x: float, y: float, half: float
) -> Landmark:
    g = georef()
    lat = g.gps_botm_left[0] + y / 111_300.0
    lng = g.gps_botm_left[1] + x / 111_300.0
    d = half / 111_300.0
    footprint = ((lat - d, lng - d), (lat - d, lng + d), (lat + d, lng + d), (lat + d, lng - d))
    return Landmark(lid, f"{category} {lid}", category, description, (lat, lng), footprint, 8.0)


def town_world() -> WorldTile:
    """Two crossing roads (north-south at x = 300 m, east-west at y = 300 m), a red-roofed
    restaurant (1) at (300, 420), a black-roofed restaurant (2) at (420, 300), a church
    (3) at (180, 300), and a red house without a landmark at (230, 230)."""
    bgr = np.full((SIZE, SIZE, 3), (90, 140, 90), np.uint8)
    semantic = np.full((SIZE, SIZE), SemanticClass.GRASS, np.uint8)
    instance = np.zeros((SIZE, SIZE), np.uint16)
    heights = np.zeros((SIZE, SIZE), np.float32)
    ns = (slice(0, SIZE), slice(round(300 / MPP) - 12, round(300 / MPP) + 12))
    ew = (slice(round(SIZE - 300 / MPP) - 12, round(SIZE - 300 / MPP) + 12), slice(0, SIZE))
    for road in (ns, ew):
        bgr[road] = (60, 60, 60)
        semantic[road] = SemanticClass.ROAD
    buildings = [
        (1, 300.0 + 25.0, 420.0, 10.0, (40, 40, 200)),  # beside the road, red roof
        (2, 420.0, 300.0 + 25.0, 10.0, (30, 30, 30)),
        (3, 180.0, 300.0 + 30.0, 15.0, (40, 40, 190)),
        (0, 230.0, 230.0, 8.0, (40, 40, 200)),
    ]
    for lid, x, y, half, colour in buildings:
        square = rows_cols(x, y, half)
        bgr[square] = colour
        semantic[square] = SemanticClass.BUILDING
        instance[square] = lid
        heights[square] = 8.0
    landmarks = (
        _landmark(1, "restaurant", "a small restaurant with a red roof", 325.0, 420.0, 10.0),
        _landmark(2, "restaurant", "a small restaurant with a black roof", 420.0, 325.0, 10.0),
        _landmark(3, "church", "a church with a cross-shaped red roof", 180.0, 330.0, 15.0),
    )
    return WorldTile("town", georef(), bgr, semantic, instance, heights, landmarks)


def town_episode(instruction: str, end_xy: tuple[float, float] = (325.0, 420.0)) -> Episode:
    """An ANDH episode on :func:`town_world`: start above the crossing heading north (120 m
    view), then a view halfway, then a 100 m view over ``end_xy`` (default: the red
    restaurant); each reachable by one official step."""
    g = georef()

    def view(x: float, y: float, heading: float, edge: float) -> list[list[float]]:
        centre = [g.gps_botm_left[0] + y / 111_300.0, g.gps_botm_left[1] + x / 111_300.0]
        return view_from_pose(centre, heading, edge).tolist()

    record = {
        "map_name": "town",
        "route_index": "1_1",
        "last_round_idx": 1,
        "instructions": f"[INS] {instruction}",
        "pre_dialogs": [],
        "gps_botm_left": list(g.gps_botm_left),
        "gps_top_right": list(g.gps_top_right),
        "lng_ratio": g.lng_ratio,
        "lat_ratio": g.lat_ratio,
        "angle": 0.0,
        "gt_path_corners": [
            view(300.0, 300.0, 0.0, 120.0),
            view((300.0 + end_xy[0]) / 2, (300.0 + end_xy[1]) / 2, 10.0, 140.0),
            view(*end_xy, 10.0, 100.0),
        ],
        "attention_list": [],
    }
    return Episode("toy", "andh", (parse_record(record),))
