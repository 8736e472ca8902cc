"""The drone's front camera: a pinhole camera over the world's height field.

The camera is fixed to the body: it pitches down between 0 (horizon ahead) and 90
degrees (straight down) but cannot yaw, so to look around the drone turns (the yaw given
to :func:`render_camera` is the body's). It gives an RGB image, a depth image and, on
synthetic tiles, semantic and landmark-instance images. On xView maps (image only) the
ground is flat, so depth comes from the altitude alone.

Rays are marched down through a fixed number of height levels over the height layer, so
roofs occlude what is behind them (:mod:`.march`); every image is one ``cv2.remap`` of a
world layer. The views a drone takes from one position (a decision's panorama) are rendered
as one batch (:meth:`CameraRig.capture_many`). The rays, the march and each hit's map
pixel run in compiled C by default (``method="native"``, :mod:`.native_march`: built on
first use, numpy with a warning when no C compiler is found); ``"fast"`` is the tiled
numpy march and ``"reference"`` the plain one that samples every ray at every level, both
with the numpy look-up (:func:`hit_coordinates`). All three give the same images, bit for
bit.
Frames: ENU metres from the map's south-west corner (:mod:`skyvln_eval.frames`); image
``u`` to the right, ``v`` down, pixel centres at ``+0.5``; depth is *planar* (distance
along the optical axis), so a pixel's point is ``camera + depth * ray(u, v)``.
"""

from __future__ import annotations

import functools
import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError
from skyvln_eval.sensing import (
    SEMANTIC_NONE,
    CameraConfig,
    CameraImages,
    CameraPose,
    camera_basis,
    pixel_rays,
    plane_coordinates,
    plane_rays,
)
from skyvln_eval.sim.march import map_scale, march, march_reference, sample_layer
from skyvln_eval.sim.native_march import march_native, native_hit_coords, native_rays
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
_BGRA: weakref.WeakKeyDictionary[WorldTile, NDArray[np.uint8]] = weakref.WeakKeyDictionary()

FloatImage = NDArray[np.float32]
#: ``native``: the march in C (:func:`~skyvln_eval.sim.native_march.march_native`, ``fast``
#: without a C compiler); ``fast``: the tiled numpy march (:func:`~skyvln_eval.sim.march.march`);
#: ``reference``: every ray at every level (:func:`~skyvln_eval.sim.march.march_reference`).
#: Same images.
RenderMethod = Literal["native", "fast", "reference"]


@functools.lru_cache(maxsize=8)
def _image_plane(config: CameraConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The ``a``, ``b`` of :func:`pixel_rays` at every pixel centre: fixed per camera."""
    v, u = np.mgrid[0 : config.height_px, 0 : config.width_px].astype(np.float64) + 0.5
    a, b = plane_coordinates(config, u, v)
    a.flags.writeable = b.flags.writeable = False
    return a, b


@functools.lru_cache(maxsize=32)
def _nudges(config: CameraConfig, pitch_deg: float, metres_per_pixel: float) -> NDArray[np.float64]:
    """Per pixel, the depth (at most 2) by which its ray moves one map pixel horizontally.

    A ray ``forward + a right - b up`` of a camera without roll moves
    ``hypot(cos(pitch) - b sin(pitch), a)`` horizontally per unit of planar depth,
    whatever the yaw, so this is fixed per camera and pitch (made once, not per view).
    """
    a, b = _image_plane(config)
    pitch = math.radians(pitch_deg)
    horizontal = np.maximum(np.hypot(math.cos(pitch) - b * math.sin(pitch), a), 1e-6)
    nudges = np.minimum(metres_per_pixel / horizontal, 2.0)
    nudges.flags.writeable = False
    return nudges


def _bgra(world: WorldTile) -> NDArray[np.uint8]:
    """The map image with a fourth channel, made once per world: OpenCV's bilinear lookup
    is vectorised for four channels and not for three (2-3x faster, the same values)."""
    if world not in _BGRA:
        _BGRA[world] = np.asarray(cv2.cvtColor(world.bgr, cv2.COLOR_BGR2BGRA), np.uint8)
    return _BGRA[world]


def enu_to_map_px(
    world: WorldTile, x_m: FloatImage, y_m: FloatImage
) -> tuple[FloatImage, FloatImage]:
    """ENU metres to sub-pixel coordinates of the resized map grid (pixel centres at integers)."""
    mpp, top_m = map_scale(world)  # the scale the march and the C look-up use
    return (x_m / mpp).astype(np.float32), ((top_m - y_m) / mpp).astype(np.float32)


def hit_coordinates(
    world: WorldTile,
    origin: NDArray[np.float64],
    rays: NDArray[np.float64],
    depth: FloatImage,
    nudge: NDArray[np.float64],
    max_depth_m: float,
) -> tuple[FloatImage, FloatImage, FloatImage]:
    """For rays ``(3, ...)`` from ``origin``, their planar depths ``(...)`` and nudges
    (:func:`_nudges`): the map pixel (``px``, ``py``) whose layers each shows, and the
    depths with anything beyond ``max_depth_m`` made inf (the depth sensor's range). A
    sky ray looks off the map.

    This is the reference; :func:`~.native_march.native_hit_coords` does the same float
    operations in C, in one pass.
    """
    sky = ~np.isfinite(depth)
    # Look the hit up one map pixel further along the ray: a wall is met on the edge of its
    # footprint, and the nearest pixel there may be the ground in front of it.
    t = np.where(sky, 0.0, depth + nudge)
    px, py = enu_to_map_px(
        world,
        (origin[0] + t * rays[0]).astype(np.float32),
        (origin[1] + t * rays[1]).astype(np.float32),
    )
    px[sky] = -1e6  # off the map: sampled as the border value
    depth = np.where(depth > max_depth_m, np.inf, depth).astype(np.float32)
    return px, py, depth


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
    if method not in ("native", "fast", "reference"):
        raise ConfigError(f"render method must be 'native', 'fast' or 'reference', got {method!r}")
    plane = _image_plane(config)
    native = method == "native"
    # Each component contiguous: (3, views, H, W); in C when the library is there.
    rays = None
    if native:
        rays = native_rays(np.array([np.concatenate(camera_basis(p)) for p in poses]), *plane)
    if rays is None:
        rays = np.empty((3, len(poses), config.height_px, config.width_px))
        for index, pose in enumerate(poses):
            rays[:, index] = np.moveaxis(plane_rays(pose, *plane), -1, 0)
    along_last = np.moveaxis(rays, 0, -1)  # (views, H, W, 3), as the marches take them
    if native:
        depth = march_native(world, origin, along_last, config.height_levels)
    elif method == "fast":
        depth = march(world, origin, along_last, config.height_levels)
    else:
        depth = np.stack(
            [march_reference(world, origin, r, config.height_levels) for r in along_last]
        )
    # The views stacked into one tall image: one lookup per layer for the whole batch.
    n, height, width = depth.shape
    sky = ~np.isfinite(depth.reshape(n * height, width))  # rays that meet nothing
    mpp = world.metres_per_pixel
    nudge = np.stack([_nudges(config, pose.pitch_deg, mpp) for pose in poses])
    coords = None
    if native:
        coords = native_hit_coords(world, origin, rays, depth, nudge, config.max_depth_m)
    if coords is None:
        coords = hit_coordinates(world, origin, rays, depth, nudge, config.max_depth_m)
    px, py, depth = (a.reshape(n * height, width) for a in coords)
    bgra = sample_layer(_bgra(world), px, py, nearest=False, fill=0.0)
    rgb = np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGB), np.uint8)
    rgb[sky] = SKY_BGR[::-1]
    semantic = instance = None
    if world.semantic is not None:
        semantic = sample_layer(world.semantic, px, py, nearest=True, fill=float(SEMANTIC_NONE))
    if world.instance is not None:
        instance = sample_layer(world.instance, px, py, nearest=True, fill=0.0)
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
