"""Ray marching over a height field: the first surface each camera ray meets.

A ray is sampled where it crosses ``levels`` heights, from the map's top (or just below the
camera) down to the ground; a hit is interpolated between the last level above the surface
and the first below it. Along a ray, map pixel coordinates are linear in the level's
height, so each level costs two multiply-adds and one bilinear height lookup.

:func:`march_reference` samples every ray at every level, one ``cv2.remap`` of the whole
image per level. :func:`march` gives the same depths, bit for bit, with far fewer samples:
it skips, per 16 x 16 pixel tile, the levels above the tallest point under the tile's rays
(found in a max-pyramid of the height layer, built once per world), where no sample can
reach its level, and it samples only the rays still in flight, of any number of views at
once (one remap per level for a whole decision's panorama).
"""

from __future__ import annotations

import math
import weakref
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.worlds.tile import WorldTile

FloatImage = NDArray[np.float32]
TILE_PX = 16
#: Map pixels per cell of the finest max-pyramid level.
CELL_PX = 16

_MAX_HEIGHTS: weakref.WeakKeyDictionary[WorldTile, float] = weakref.WeakKeyDictionary()
_MIN_HEIGHTS: weakref.WeakKeyDictionary[WorldTile, float] = weakref.WeakKeyDictionary()
_PYRAMIDS: weakref.WeakKeyDictionary[WorldTile, NDArray[np.float32]] = weakref.WeakKeyDictionary()


def sample_layer(
    layer: NDArray[Any], px: FloatImage, py: FloatImage, nearest: bool, fill: float
) -> NDArray[Any]:
    """``layer`` at sub-pixel map coordinates (``fill`` outside the map)."""
    out: NDArray[Any] = cv2.remap(
        np.asarray(layer),
        px,
        py,
        interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=fill,
    )
    return out


def max_height_m(world: WorldTile) -> float:
    """The tallest point of the map (0 without a height layer), computed once per world."""
    if world not in _MAX_HEIGHTS:
        _MAX_HEIGHTS[world] = 0.0 if world.height_m is None else float(world.height_m.max())
    return _MAX_HEIGHTS[world]


def min_height_m(world: WorldTile) -> float:
    """The lowest point of the map (0 without a height layer), computed once per world."""
    if world not in _MIN_HEIGHTS:
        _MIN_HEIGHTS[world] = 0.0 if world.height_m is None else float(world.height_m.min())
    return _MIN_HEIGHTS[world]


class _Frame:
    """The march's per-ray quantities: at height z (``k = z - origin_z``) a ray is at map
    pixel ``(x0 + k sx, y0 - k sy)`` and at distance ``k inv_dz`` along its planar depth."""

    def __init__(self, world: WorldTile, origin: NDArray[np.float64], rays: NDArray[Any]) -> None:
        dz = rays[..., 2]
        self.down = dz < -1e-9
        safe_dz = np.where(self.down, dz, -1.0)
        self.ground_t = (0.0 - origin[2]) / safe_dz
        mpp, top_m = map_scale(world)
        self.inv_dz = (1.0 / safe_dz).astype(np.float32)
        self.sx = (rays[..., 0] / safe_dz / mpp).astype(np.float32)
        self.sy = (rays[..., 1] / safe_dz / mpp).astype(np.float32)
        self.x0, self.y0 = np.float32(origin[0] / mpp), np.float32((top_m - origin[1]) / mpp)


def map_scale(world: WorldTile) -> tuple[float, float]:
    """Metres per map pixel, and the map's north edge in ENU metres (map row 0)."""
    mpp = world.georef.lat_ratio * METERS_PER_DEGREE
    (lat0, _), (lat1, _) = world.georef.gps_botm_left, world.georef.gps_top_right
    return mpp, (lat1 - lat0) * METERS_PER_DEGREE


def _levels(world: WorldTile, origin: NDArray[np.float64], levels: int) -> NDArray[np.float64]:
    return np.linspace(min(max_height_m(world), origin[2] - 1e-3), 0.0, levels)


def march_reference(
    world: WorldTile, origin: NDArray[np.float64], rays: NDArray[np.float64], levels: int
) -> FloatImage:
    """Planar depth of the first surface each downward ray of one image ``(H, W, 3)`` meets
    (``inf`` for rays that go up), sampling every ray at every level."""
    frame = _Frame(world, origin, rays)
    down = frame.down
    if world.height_m is None or max_height_m(world) <= 0.0:
        return np.where(down, frame.ground_t, np.inf).astype(np.float32)
    hit_t = frame.ground_t.astype(np.float32).ravel()
    found = (~down).ravel()
    flat_inv_dz = frame.inv_dz.ravel()
    previous: tuple[np.float32, NDArray[np.float32]] | None = None
    for z_level in _levels(world, origin, levels):
        k = np.float32(z_level - origin[2])
        px, py = frame.x0 + k * frame.sx, frame.y0 - k * frame.sy
        gap = sample_layer(world.height_m, px, py, nearest=False, fill=0.0)
        gap = (gap - np.float32(z_level)).ravel()
        # Only the rays that meet the surface at this level are worked on.
        new = np.flatnonzero((gap >= 0.0) & ~found)
        if len(new):
            t = k * flat_inv_dz[new]
            if previous is None:
                hit_t[new] = t
            else:
                previous_k, previous_gap = previous
                hit_t[new] = _crossing(previous_k, previous_gap[new], gap[new], t, flat_inv_dz[new])
            found[new] = True
            if found.all():
                break
        previous = (k, gap)
    return np.where(down, hit_t.reshape(down.shape), np.inf).astype(np.float32)


def _crossing(
    previous_k: np.float32,
    before: NDArray[np.float32],
    after: NDArray[np.float32],
    t: NDArray[np.float32],
    inv_dz: NDArray[np.float32],
) -> NDArray[np.float32]:
    """Where the ray crossed the surface between the previous level (gap < 0) and this one."""
    previous_t = previous_k * inv_dz
    fraction = np.clip(before / np.minimum(before - after, -1e-9), 0.0, 1.0)
    result: NDArray[np.float32] = previous_t + fraction * (t - previous_t)
    return result


def march(
    world: WorldTile, origin: NDArray[np.float64], rays: NDArray[np.float64], levels: int
) -> FloatImage:
    """The depths of :func:`march_reference` for rays ``(V, H, W, 3)`` of ``V`` images seen
    from one ``origin``, sampling each tile of rays only from the first level its terrain
    can reach, until all its rays have hit."""
    frame = _Frame(world, origin, rays)
    down = frame.down
    if world.height_m is None or max_height_m(world) <= 0.0:
        return np.where(down, frame.ground_t, np.inf).astype(np.float32)
    z_levels = _levels(world, origin, levels)
    tiles = _Tiles(down.shape)
    start = _start_levels(world, origin, frame, tiles, z_levels)
    # Tiles in the order they join, so that the tiles in flight are always a prefix: slices,
    # not gathers (a tile whose rays have all hit is sampled on, its results left alone).
    order = np.argsort(start, kind="stable")
    joined = np.searchsorted(start[order], np.arange(1, levels + 1))
    sx, sy = tiles.split(frame.sx)[order], tiles.split(frame.sy)[order]
    inv_dz = tiles.split(frame.inv_dz)[order]
    hit_t = tiles.split(frame.ground_t.astype(np.float32))[order]
    # Rays still in flight; rays that go up (and padding) never hit.
    flying = tiles.split(down, fill=False)[order]
    previous_gap: NDArray[np.float32] = np.zeros((0, TILE_PX, TILE_PX), dtype=np.float32)
    previous_k = np.float32(0.0)
    for j, z_level in enumerate(z_levels):
        n = int(joined[j])
        if n == 0:
            continue
        k = np.float32(z_level - origin[2])
        px, py = frame.x0 + k * sx[:n], frame.y0 - k * sy[:n]
        # remap walks its maps row by row: one tile (256 rays) per row, not 16 rows of 16.
        gap = sample_layer(
            world.height_m,
            px.reshape(n, TILE_PX * TILE_PX),
            py.reshape(n, TILE_PX * TILE_PX),
            nearest=False,
            fill=0.0,
        ).reshape(n, TILE_PX, TILE_PX)
        gap -= np.float32(z_level)
        hits = gap >= 0.0
        hits &= flying[:n]
        # Look for the hits only in tiles that have some (a few at most levels).
        hit_tiles = np.flatnonzero(hits.reshape(n, -1).any(axis=1))
        if len(hit_tiles):
            tile, row, col = np.nonzero(hits[hit_tiles])
            which = (hit_tiles[tile], row, col)
            t = k * inv_dz[which]
            if j == 0:
                hit_t[which] = t
            else:
                # Tiles that joined at this level cannot hit at it: the previous level's
                # gaps cover every tile that can.
                before = previous_gap[which]
                hit_t[which] = _crossing(previous_k, before, gap[which], t, inv_dz[which])
            flying[which] = False
        previous_gap, previous_k = gap, k
    in_place = np.empty_like(hit_t)
    in_place[order] = hit_t
    return np.where(down, tiles.join(in_place), np.inf).astype(np.float32)


class _Tiles:
    """Images ``(V, H, W)`` as ``TILE_PX`` square tiles ``(T, TILE_PX, TILE_PX)`` and back:
    a tile's rays meet nearby map pixels, so sampling tile by tile stays cache-friendly."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.views, self.height, self.width = shape
        self.rows, self.cols = -(-self.height // TILE_PX), -(-self.width // TILE_PX)

    def split(self, image: NDArray[Any], fill: Any = 0) -> NDArray[Any]:
        padded = np.full(
            (self.views, self.rows * TILE_PX, self.cols * TILE_PX), fill, dtype=image.dtype
        )
        padded[:, : self.height, : self.width] = image
        grid = padded.reshape(self.views, self.rows, TILE_PX, self.cols, TILE_PX)
        return np.ascontiguousarray(grid.transpose(0, 1, 3, 2, 4)).reshape(-1, TILE_PX, TILE_PX)

    def join(self, tiles: NDArray[Any]) -> NDArray[Any]:
        grid = tiles.reshape(self.views, self.rows, self.cols, TILE_PX, TILE_PX)
        image = grid.transpose(0, 1, 3, 2, 4).reshape(
            self.views, self.rows * TILE_PX, self.cols * TILE_PX
        )
        return image[:, : self.height, : self.width]


def _corners(image: NDArray[Any], tiles: _Tiles) -> NDArray[Any]:
    """The values at each tile's four corner pixels, ``(tiles, 4)`` in :class:`_Tiles` order."""
    r0 = np.minimum(np.arange(tiles.rows) * TILE_PX, tiles.height - 1)
    c0 = np.minimum(np.arange(tiles.cols) * TILE_PX, tiles.width - 1)
    r1, c1 = (
        np.minimum(r0 + TILE_PX - 1, tiles.height - 1),
        np.minimum(c0 + TILE_PX - 1, tiles.width - 1),
    )
    rows = np.stack(np.broadcast_arrays(r0[:, None], r0[:, None], r1[:, None], r1[:, None]))
    cols = np.stack(np.broadcast_arrays(c0[None], c1[None], c0[None], c1[None]))
    # (views, 4, tile rows, tile cols) -> (tiles, 4)
    return image[:, rows, cols].transpose(0, 2, 3, 1).reshape(-1, 4)


def _start_levels(
    world: WorldTile,
    origin: NDArray[np.float64],
    frame: _Frame,
    tiles: _Tiles,
    z_levels: NDArray[np.float64],
) -> NDArray[np.int64]:
    """Per tile, the first level to sample: the level before the first one where the
    tallest point under the tile's footprint at that level reaches the level's height (so
    the level before a hit is always sampled); 0 for a tile with rays on both sides of the
    horizon; ``levels`` (never) for tiles whose rays all go up."""
    sx = _corners(frame.sx, tiles).astype(np.float64).T  # (4 corners, tiles)
    sy = _corners(frame.sy, tiles).astype(np.float64).T
    down = _corners(frame.down, tiles)
    # With all its rays going down, a tile's footprint at a level is the quad of its corner
    # rays there: its box, per tile and level (corners first: four contiguous arrays).
    ks = (z_levels - origin[2])[None, None, :]
    xs = float(frame.x0) + ks * sx[:, :, None]
    ys = float(frame.y0) - ks * sy[:, :, None]
    tallest = _box_max(
        world,
        np.minimum(np.minimum(xs[0], xs[1]), np.minimum(xs[2], xs[3])),
        np.maximum(np.maximum(xs[0], xs[1]), np.maximum(xs[2], xs[3])),
        np.minimum(np.minimum(ys[0], ys[1]), np.minimum(ys[2], ys[3])),
        np.maximum(np.maximum(ys[0], ys[1]), np.maximum(ys[2], ys[3])),
    )
    # Bilinear samples never exceed their neighbours; the slack covers float32 rounding.
    reaches = tallest * (1.0 + 1e-5) + 1e-3 >= z_levels[None, :]
    first = np.argmax(reaches, axis=1)  # the ground level always reaches
    start = np.where(down.all(axis=1), np.maximum(first - 1, 0), 0)
    return np.where(down.any(axis=1), start, len(z_levels))


def _box_max(
    world: WorldTile,
    x_min: NDArray[np.float64],
    x_max: NDArray[np.float64],
    y_min: NDArray[np.float64],
    y_max: NDArray[np.float64],
) -> NDArray[np.float64]:
    """An upper bound of the height layer over each map pixel box (2 px margin): the max of
    the 2 x 2 cells of the pyramid level whose cells are at least as large as the box."""
    pyramid = _pyramid(world)
    cells_y, cells_x = pyramid.shape[1:]
    extent = np.maximum(x_max - x_min, y_max - y_min) + 4.0
    level = np.clip(np.ceil(np.log2(np.maximum(extent / CELL_PX, 1.0))), 0, len(pyramid) - 1)
    level = np.where(np.isfinite(extent), level, len(pyramid) - 1).astype(np.int64)
    size = CELL_PX * (2.0**level)
    out = np.zeros(level.shape)
    # Cell indices of the box's low and high edges (the coordinates are finite).
    cx = [
        np.minimum(np.maximum(x // size, 0), cells_x - 1).astype(np.int64)
        for x in (x_min - 2.0, x_max + 2.0)
    ]
    cy = [
        np.minimum(np.maximum(y // size, 0), cells_y - 1).astype(np.int64)
        for y in (y_min - 2.0, y_max + 2.0)
    ]
    for row in cy:
        for col in cx:
            out = np.maximum(out, pyramid[level, row, col])
    return out


def _pyramid(world: WorldTile) -> NDArray[np.float32]:
    """Max-pyramid of the height layer: level ``l`` holds the max over cells of
    ``CELL_PX * 2**l`` map pixels (coarser levels in the top-left corner of the array);
    the last level is one cell, the whole map."""
    if world in _PYRAMIDS:
        return _PYRAMIDS[world]
    heights = np.asarray(world.height_m, dtype=np.float32)
    rows, cols = heights.shape
    cy, cx = math.ceil(rows / CELL_PX), math.ceil(cols / CELL_PX)
    padded = np.zeros((cy * CELL_PX, cx * CELL_PX), np.float32)
    padded[:rows, :cols] = heights
    cells = padded.reshape(cy, CELL_PX, cx, CELL_PX).max(axis=(1, 3))
    levels = [cells]
    while max(levels[-1].shape) > 1:
        last = levels[-1]
        ly, lx = last.shape
        even = np.zeros((ly + ly % 2, lx + lx % 2), np.float32)
        even[:ly, :lx] = last
        levels.append(even.reshape(even.shape[0] // 2, 2, even.shape[1] // 2, 2).max(axis=(1, 3)))
    pyramid = np.zeros((len(levels), cy, cx), np.float32)
    for index, level in enumerate(levels):
        pyramid[index, : level.shape[0], : level.shape[1]] = level
    _PYRAMIDS[world] = pyramid
    return pyramid
