"""The drone's front camera: a pinhole camera over the world's height field.

The camera is fixed to the body: it pitches down between 0 (horizon ahead) and 90
degrees (straight down) but cannot yaw, so to look around the drone turns (the yaw given
to :func:`render_camera` is the body's). It gives an RGB image, a depth image and, on
synthetic tiles, semantic and landmark-instance images. On xView maps (image only) the
ground is flat, so depth comes from the altitude alone.

Rays are marched down through a fixed number of height levels over the height layer, so
roofs occlude what is behind them (:mod:`.march`); every image is one ``cv2.remap`` of a
world layer. The views a drone takes from one position (a decision's panorama) are rendered
as one batch (:meth:`CameraRig.capture_many`). The march runs in compiled C by default
(``method="native"``, :mod:`.native_march`: built on first use, numpy with a warning when
no C compiler is found); ``"fast"`` is the tiled numpy march and ``"reference"`` the plain
one that samples every ray at every level. All three give the same depths, bit for bit.
Frames: ENU metres from the map's south-west corner (:mod:`skyvln_eval.frames`); image
``u`` to the right, ``v`` down, pixel centres at ``+0.5``; depth is *planar* (distance
along the optical axis), so a pixel's point is ``camera + depth * ray(u, v)``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.errors import ConfigError
from skyvln_eval.sensing import (
    SEMANTIC_NONE,
    CameraConfig,
    CameraImages,
    CameraPose,
    camera_basis,
    pixel_rays,
    plane_coordinates,
)
from skyvln_eval.sim.march import march, march_reference, sample_layer
from skyvln_eval.sim.native_march import march_native
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
#: ``native``: the march in C (:func:`~skyvln_eval.sim.native_march.march_native`, ``fast``
#: without a C compiler); ``fast``: the tiled numpy march (:func:`~skyvln_eval.sim.march.march`);
#: ``reference``: every ray at every level (:func:`~skyvln_eval.sim.march.march_reference`).
#: Same images.
RenderMethod = Literal["native", "fast", "reference"]


def _rays(pose: CameraPose, a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``forward + a right - b up``, computed one component at a time (numpy is slow on an
    innermost axis of 3; the operations, and so the values, are the same), returned as a
    ``(..., 3)`` view whose components are contiguous."""
    forward, right, up = camera_basis(pose)
    rays = np.empty((3, *np.shape(a)))
    scratch = np.empty(np.shape(b))
    for c in range(3):
        component = rays[c, ...]  # a view, also for a single point
        np.multiply(a, right[c], out=component)
        component += forward[c]
        component -= np.multiply(b, up[c], out=scratch)
    return np.moveaxis(rays, 0, -1)


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


def render_camera(
    world: WorldTile,
    pose: CameraPose,
    config: CameraConfig | None = None,
    method: RenderMethod = "native",
) -> CameraImages:
    """What the front camera sees from ``pose`` over ``world``."""
    return render_views(world, [pose], config, method)[0]


def render_views(
    world: WorldTile,
    poses: Sequence[CameraPose],
    config: CameraConfig | None = None,
    method: RenderMethod = "native",
) -> list[CameraImages]:
    """What the front camera sees from each pose, all at one position, rendered as a batch."""
    config = config or CameraConfig()
    if not poses:
        return []
    origin = np.array([poses[0].x_m, poses[0].y_m, poses[0].z_m])
    for pose in poses[1:]:
        if (pose.x_m, pose.y_m, pose.z_m) != tuple(origin):
            raise ConfigError("render_views renders views from one position: the poses differ")
    plane = _image_plane(config)
    rays = np.empty((3, len(poses), config.height_px, config.width_px))
    for index, pose in enumerate(poses):
        rays[:, index] = np.moveaxis(_rays(pose, *plane), -1, 0)
    rays = np.moveaxis(rays, 0, -1)  # (views, H, W, 3), each component contiguous
    if method == "native":
        depth = march_native(world, origin, rays, config.height_levels)
    elif method == "fast":
        depth = march(world, origin, rays, config.height_levels)
    elif method == "reference":
        depth = np.stack([march_reference(world, origin, r, config.height_levels) for r in rays])
    else:
        raise ConfigError(f"render method must be 'native', 'fast' or 'reference', got {method!r}")
    # The views stacked into one tall image: one lookup per layer for the whole batch.
    n, height, width = depth.shape
    stacked = rays.reshape(n * height, width, 3)
    depth = depth.reshape(n * height, width)
    sky = ~np.isfinite(depth)
    # Look the hit up one map pixel further along the ray: a wall is met on the edge of its
    # footprint, and the nearest pixel there may be the ground in front of it.
    horizontal = np.maximum(np.hypot(stacked[..., 0], stacked[..., 1]), 1e-6)
    nudge = np.minimum(world.metres_per_pixel / horizontal, 2.0)
    t = np.where(sky, 0.0, depth + nudge)
    px, py = enu_to_map_px(
        world,
        (origin[0] + t * stacked[..., 0]).astype(np.float32),
        (origin[1] + t * stacked[..., 1]).astype(np.float32),
    )
    px[sky] = -1e6  # off the map: sampled as the border value
    bgr = sample_layer(world.bgr, px, py, nearest=False, fill=0.0)
    bgr[sky] = SKY_BGR
    semantic = instance = None
    if world.semantic is not None:
        semantic = sample_layer(world.semantic, px, py, nearest=True, fill=float(SEMANTIC_NONE))
    if world.instance is not None:
        instance = sample_layer(world.instance, px, py, nearest=True, fill=0.0)
    depth = np.where(depth > config.max_depth_m, np.inf, depth).astype(np.float32)
    # Contiguous, so each view's copy below is one memcpy (not a gather of reversed channels).
    rgb = np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
    images = []
    for index, pose in enumerate(poses):
        rows = slice(index * height, (index + 1) * height)
        images.append(
            CameraImages(
                pose=pose,
                config=config,
                rgb=rgb[rows].copy(),  # its own memory, not a view of the batch
                depth_m=depth[rows],
                semantic=None if semantic is None else semantic[rows].astype(np.uint8),
                instance=None if instance is None else instance[rows].astype(np.uint16),
            )
        )
    return images


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
        return self.capture_many([(yaw_rad, pitch_deg)], config)[0]

    def capture_many(
        self, headings: Sequence[tuple[float, float]], config: CameraConfig | None = None
    ) -> list[CameraImages]:
        """The images after turning to each ``(yaw_rad, pitch_deg)``, rendered as one batch
        (the same images as one :meth:`capture` each, faster)."""
        poses = [CameraPose(self.x_m, self.y_m, self.z_m, yaw, pitch) for yaw, pitch in headings]
        return render_views(self.world, poses, config or self.config)
