"""The drone's front camera: a pinhole camera over the world's height field.

The camera is fixed to the body: it pitches down between 0 (horizon ahead) and 90
degrees (straight down) but cannot yaw, so to look around the drone turns (the yaw given
to :func:`render_camera` is the body's). It gives an RGB image, a depth image and, on
synthetic tiles, semantic and landmark-instance images. On xView maps (image only) the
ground is flat, so depth comes from the altitude alone.

Rays are marched down through a fixed number of height levels over the height layer, so
roofs occlude what is behind them; every image is one ``cv2.remap`` of a world layer.
Frames: ENU metres from the map's south-west corner (:mod:`skyvln_eval.frames`); image
``u`` to the right, ``v`` down, pixel centres at ``+0.5``; depth is *planar* (distance
along the optical axis), so a pixel's point is ``camera + depth * ray(u, v)``.
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import dataclass, field
from typing import Any, Final

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.sensing import (
    SEMANTIC_NONE,
    CameraConfig,
    CameraImages,
    CameraPose,
    camera_basis,
    pixel_rays,
    plane_coordinates,
)
from skyvln_eval.worlds.tile import WorldTile

__all__ = [
    "SEMANTIC_NONE",
    "CameraConfig",
    "CameraImages",
    "CameraPose",
    "CameraRig",
    "camera_basis",
    "enu_to_map_px",
    "pixel_rays",
    "render_camera",
]

SKY_BGR: Final = (235, 206, 135)

FloatImage = NDArray[np.float32]


def _rays(pose: CameraPose, a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``forward + a right - b up``, in place where possible (same values, fewer arrays)."""
    forward, right, up = camera_basis(pose)
    rays = a[..., None] * right
    rays += forward
    rays -= b[..., None] * up
    return rays


@functools.lru_cache(maxsize=8)
def _image_plane(config: CameraConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The ``a``, ``b`` of :func:`pixel_rays` at every pixel centre: fixed per camera."""
    v, u = np.mgrid[0 : config.height_px, 0 : config.width_px].astype(np.float64) + 0.5
    a, b = plane_coordinates(config, u, v)
    a.flags.writeable = b.flags.writeable = False
    return a, b


def enu_to_map_px(
    world: WorldTile, x_m: FloatImage, y_m: FloatImage
) -> tuple[FloatImage, FloatImage]:
    """ENU metres to sub-pixel coordinates of the resized map grid (pixel centres at integers)."""
    mpp = world.georef.lat_ratio * METERS_PER_DEGREE
    (lat0, _), (lat1, _) = world.georef.gps_botm_left, world.georef.gps_top_right
    top_m = (lat1 - lat0) * METERS_PER_DEGREE
    return (x_m / mpp).astype(np.float32), ((top_m - y_m) / mpp).astype(np.float32)


def _sample(
    layer: NDArray[Any], px: FloatImage, py: FloatImage, nearest: bool, fill: float
) -> NDArray[Any]:
    out: NDArray[Any] = cv2.remap(
        np.asarray(layer),
        px,
        py,
        interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=fill,
    )
    return out


_MAX_HEIGHTS: weakref.WeakKeyDictionary[WorldTile, float] = weakref.WeakKeyDictionary()


def _max_height_m(world: WorldTile) -> float:
    """The tallest point of the map (0 without a height layer), computed once per world."""
    if world not in _MAX_HEIGHTS:
        _MAX_HEIGHTS[world] = 0.0 if world.height_m is None else float(world.height_m.max())
    return _MAX_HEIGHTS[world]


def _march(
    world: WorldTile, origin: NDArray[np.float64], rays: NDArray[np.float64], levels: int
) -> FloatImage:
    """Planar depth of the first surface each downward ray meets (``inf`` for rays that go up).

    The ray is sampled where it crosses ``levels`` heights from the map's top down to the
    ground; a hit is interpolated between the last level above the surface and the first
    below it. Along a ray, map pixel coordinates are linear in the level's height, so each
    level costs two multiply-adds and one height lookup.
    """
    dz = rays[..., 2]
    down = dz < -1e-9
    safe_dz = np.where(down, dz, -1.0)
    ground_t = (0.0 - origin[2]) / safe_dz
    max_height = _max_height_m(world)
    if world.height_m is None or max_height <= 0.0:
        return np.where(down, ground_t, np.inf).astype(np.float32)
    top = min(max_height, origin[2] - 1e-3)
    mpp = world.georef.lat_ratio * METERS_PER_DEGREE
    (lat0, _), (lat1, _) = world.georef.gps_botm_left, world.georef.gps_top_right
    top_m = (lat1 - lat0) * METERS_PER_DEGREE
    # At height z, with k = z - origin_z: t = k / dz, px = x0 + k * sx, py = y0 - k * sy.
    inv_dz = (1.0 / safe_dz).astype(np.float32)
    sx = (rays[..., 0] / safe_dz / mpp).astype(np.float32)
    sy = (rays[..., 1] / safe_dz / mpp).astype(np.float32)
    x0, y0 = np.float32(origin[0] / mpp), np.float32((top_m - origin[1]) / mpp)
    hit_t = ground_t.astype(np.float32).ravel()
    found = (~down).ravel()
    flat_inv_dz = inv_dz.ravel()
    previous: tuple[np.float32, NDArray[np.float32]] | None = None
    for z_level in np.linspace(top, 0.0, levels):
        k = np.float32(z_level - origin[2])
        gap = _sample(world.height_m, x0 + k * sx, y0 - k * sy, nearest=False, fill=0.0)
        gap = (gap - np.float32(z_level)).ravel()
        # Only the rays that meet the surface at this level are worked on.
        new = np.flatnonzero((gap >= 0.0) & ~found)
        if len(new):
            t = k * flat_inv_dz[new]
            if previous is None:
                hit_t[new] = t
            else:
                # The ray crossed the surface between the previous level (gap < 0) and this.
                previous_k, previous_gap = previous
                previous_t = previous_k * flat_inv_dz[new]
                before, after = previous_gap[new], gap[new]
                fraction = np.clip(before / np.minimum(before - after, -1e-9), 0.0, 1.0)
                hit_t[new] = previous_t + fraction * (t - previous_t)
            found[new] = True
            if found.all():
                break
        previous = (k, gap)
    hit_t = hit_t.reshape(dz.shape)
    return np.where(down, hit_t, np.inf).astype(np.float32)


def render_camera(
    world: WorldTile, pose: CameraPose, config: CameraConfig | None = None
) -> CameraImages:
    """What the front camera sees from ``pose`` over ``world``."""
    config = config or CameraConfig()
    rays = _rays(pose, *_image_plane(config))
    origin = np.array([pose.x_m, pose.y_m, pose.z_m])
    depth = _march(world, origin, rays, config.height_levels)
    sky = ~np.isfinite(depth)
    # Look the hit up one map pixel further along the ray: a wall is met on the edge of its
    # footprint, and the nearest pixel there may be the ground in front of it.
    horizontal = np.maximum(np.hypot(rays[..., 0], rays[..., 1]), 1e-6)
    nudge = np.minimum(world.metres_per_pixel / horizontal, 2.0)
    t = np.where(sky, 0.0, depth + nudge)
    px, py = enu_to_map_px(
        world,
        (origin[0] + t * rays[..., 0]).astype(np.float32),
        (origin[1] + t * rays[..., 1]).astype(np.float32),
    )
    px[sky] = -1e6  # off the map: sampled as the border value
    bgr = _sample(world.bgr, px, py, nearest=False, fill=0.0)
    bgr[sky] = SKY_BGR
    semantic = instance = None
    if world.semantic is not None:
        semantic = _sample(world.semantic, px, py, nearest=True, fill=float(SEMANTIC_NONE))
    if world.instance is not None:
        instance = _sample(world.instance, px, py, nearest=True, fill=0.0)
    depth = np.where(depth > config.max_depth_m, np.inf, depth).astype(np.float32)
    return CameraImages(
        pose=pose,
        config=config,
        rgb=np.ascontiguousarray(bgr[..., ::-1]),
        depth_m=depth,
        semantic=None if semantic is None else semantic.astype(np.uint8),
        instance=None if instance is None else instance.astype(np.uint16),
    )


@dataclass(frozen=True, eq=False)
class CameraRig:
    """The camera on a drone hovering at one position: it turns the body to look around.

    ``capture(yaw_rad, pitch_deg)`` is what the front camera sees after turning in place
    to ENU yaw ``yaw_rad`` with the camera pitched down ``pitch_deg``; the drone's
    position does not change, so an agent may capture any number of headings per step.
    """

    world: WorldTile
    x_m: float
    y_m: float
    z_m: float
    config: CameraConfig = field(default_factory=CameraConfig)

    @property
    def has_layers(self) -> bool:
        return self.world.has_layers

    def capture(
        self, yaw_rad: float, pitch_deg: float, config: CameraConfig | None = None
    ) -> CameraImages:
        """The image after turning to ``yaw_rad``; ``config`` overrides the rig's optics."""
        pose = CameraPose(self.x_m, self.y_m, self.z_m, yaw_rad, pitch_deg)
        return render_camera(self.world, pose, config or self.config)
