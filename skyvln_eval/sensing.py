"""What a drone's sensors give an agent: images, the camera's geometry, and the sensor handle.

This module is the sensor boundary (as in Gymnasium: the environment owns the world and
hands out observations). It knows no world, map layer or episode: the simulator
(:mod:`skyvln_eval.sim.camera`) renders into these types and the harness hands the agent
a :class:`Sensors` handle, through which the agent can only turn in place and capture
images.

* :class:`CameraConfig` / :class:`CameraPose`: optics and where the camera is (ENU metres
  from the map's south-west corner, z above ground, body yaw in ENU radians, pitch down in
  degrees). :func:`pixel_rays` gives the ray through an image point.
* :class:`CameraImages`: one capture. RGB always; planar depth only with the depth sensor;
  semantic classes (:class:`SemanticClass`), landmark instances and each instance's
  category only with the semantic camera (a panoptic segmentation camera, as simulators
  have). Nothing in a capture names a landmark or describes it.
* :class:`SensorConfig`: which sensors the drone carries and the camera they share.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Final, Literal, Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from skyvln_eval.config_model import StrictModel
from skyvln_eval.errors import ConfigError

SensorKind = Literal["rgb", "depth", "semantic"]
#: Semantic value of pixels that see the sky or lie outside the map.
SEMANTIC_NONE: Final = 255

FloatImage = NDArray[np.float32]


class SemanticClass(IntEnum):
    """Semantic classes a semantic camera reports (and synthetic tiles store)."""

    GROUND = 0
    ROAD = 1
    SIDEWALK = 2
    BUILDING = 3
    GRASS = 4
    TREE = 5
    WATER = 6
    PARKING = 7
    VEHICLE = 8
    SPORTS_FIELD = 9
    BRIDGE = 10
    PLAZA = 11


@dataclass(frozen=True)
class CameraConfig:
    """Image size and optics; ``fov_deg`` is the horizontal field of view.

    ``max_depth_m`` is the depth sensor's range (farther pixels get ``inf`` depth but are
    still seen in RGB); ``height_levels`` the number of height levels the simulator's rays
    are marched through. Between two levels a ray moves ``level spacing / tan(depression)``
    metres sideways, so at grazing angles a building narrower than that can be missed (its
    roof is still seen from steeper rays): raise the levels for low pitches and tall
    buildings, at the cost of one image lookup per level. Rays that go up see the sky.
    """

    width_px: int = 224
    height_px: int = 224
    fov_deg: float = 90.0
    max_depth_m: float = 500.0
    height_levels: int = 24

    def __post_init__(self) -> None:
        if self.width_px < 8 or self.height_px < 8:
            raise ConfigError(
                f"camera image must be at least 8 x 8 px, got {self.width_px} x {self.height_px}"
            )
        if not 10.0 <= self.fov_deg <= 150.0:
            raise ConfigError(f"camera fov_deg must be in [10, 150], got {self.fov_deg}")
        if self.height_levels < 2:
            raise ConfigError(f"camera height_levels must be >= 2, got {self.height_levels}")

    @property
    def focal_px(self) -> float:
        return (self.width_px / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)


@dataclass(frozen=True)
class CameraPose:
    """Camera position (ENU m, z above ground), body yaw (ENU rad) and pitch down (deg)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    pitch_deg: float

    def __post_init__(self) -> None:
        if not 0.0 <= self.pitch_deg <= 90.0:
            raise ConfigError(f"camera pitch_deg must be in [0, 90] (down), got {self.pitch_deg}")
        if self.z_m <= 0.0:
            raise ConfigError(f"camera height z_m must be above ground, got {self.z_m}")


def camera_basis(pose: CameraPose) -> tuple[NDArray[np.float64], ...]:
    """Unit vectors (ENU) of the optical axis, image right and image up."""
    yaw, pitch = pose.yaw_rad, math.radians(pose.pitch_deg)
    forward = np.array(
        [math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)]
    )
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    up = np.array(
        [math.cos(yaw) * math.sin(pitch), math.sin(yaw) * math.sin(pitch), math.cos(pitch)]
    )
    return forward, right, up


def plane_coordinates(
    config: CameraConfig, u: NDArray[Any], v: NDArray[Any]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Image point ``(u, v)`` as offsets right (``a``) and down (``b``) at unit depth."""
    f = config.focal_px
    a = (np.asarray(u, dtype=np.float64) - config.width_px / 2.0) / f
    b = (np.asarray(v, dtype=np.float64) - config.height_px / 2.0) / f
    return a, b


def plane_rays(
    pose: CameraPose, a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``forward + a right - b up`` (the rays through image-plane offsets ``a``, ``b``),
    computed one component at a time (numpy is slow on an innermost axis of 3; the
    operations, and so the values, are the same), returned as a ``(..., 3)`` view whose
    components are contiguous."""
    forward, right, up = camera_basis(pose)
    rays = np.empty((3, *np.shape(a)))
    scratch = np.empty(np.shape(b))
    for c in range(3):
        component = rays[c, ...]  # a view, also for a single point
        np.multiply(a, right[c], out=component)
        component += forward[c]
        component -= np.multiply(b, up[c], out=scratch)
    return np.moveaxis(rays, 0, -1)


def pixel_rays(
    pose: CameraPose, config: CameraConfig, u: NDArray[Any], v: NDArray[Any]
) -> NDArray[np.float64]:
    """Ray directions (ENU, ``(..., 3)``, components contiguous) through image points
    ``(u, v)``, unit planar depth."""
    return plane_rays(pose, *plane_coordinates(config, u, v))


def instance_pixel_counts(
    instance: NDArray[np.uint16],
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The instance ids an instance image holds, ascending (as ``np.unique`` gives them), and
    each one's pixel count: by counting, since ids are small integers, with no sort or hash
    of the whole image (0, no landmark, included when present)."""
    counts = np.bincount(instance.ravel())
    ids = np.flatnonzero(counts)
    return ids, counts[ids]


@dataclass(frozen=True, eq=False)
class CameraImages:
    """One capture: what the drone's sensors saw in one direction.

    ``rgb`` ``(H, W, 3)`` uint8 always. ``depth_m`` planar depth (float32, ``inf`` = no
    return) with the depth sensor, else ``None``. With the semantic camera: ``semantic``
    uint8 (:class:`SemanticClass`, :data:`SEMANTIC_NONE` = sky / off-map), ``instance``
    uint16 (0 = no landmark) and ``instance_categories``, each instance's category (e.g.
    ``"gas_station"``); else ``None`` / empty.
    """

    pose: CameraPose
    config: CameraConfig
    rgb: NDArray[np.uint8]
    depth_m: FloatImage | None = None
    semantic: NDArray[np.uint8] | None = None
    instance: NDArray[np.uint16] | None = None
    instance_categories: Mapping[int, str] = field(default_factory=dict)

    @property
    def size_px(self) -> tuple[int, int]:
        """``(width, height)``."""
        height, width = self.rgb.shape[:2]
        return width, height

    def points_enu(self, u: NDArray[Any], v: NDArray[Any]) -> NDArray[np.float64]:
        """ENU points seen at pixel centres ``(u, v)`` (integer pixel indices).

        From depth where the depth sensor gave it; without depth, where the pixel's ray
        meets flat ground (z = 0): a monocular camera's best guess, right on the ground and
        short of roofs. Rays that do not reach the ground give ``inf``.
        """
        ui = np.asarray(u, dtype=np.int64)
        vi = np.asarray(v, dtype=np.int64)
        rays = pixel_rays(self.pose, self.config, ui + 0.5, vi + 0.5)
        origin = np.array([self.pose.x_m, self.pose.y_m, self.pose.z_m])
        if self.depth_m is not None:
            depth = self.depth_m[vi, ui].astype(np.float64)
        else:
            down = rays[..., 2] < -1e-9
            depth = np.where(down, -origin[2] / np.where(down, rays[..., 2], -1.0), np.inf)
        # ``origin + depth * rays`` one component at a time, as pixel_rays makes the rays
        # (the same floats; a (..., 3) view whose components are contiguous).
        points = np.empty((3, *np.shape(ui)))
        for c in range(3):
            component = points[c, ...]  # a view, also for a single point
            np.multiply(depth, rays[..., c], out=component)
            component += origin[c]
        return np.moveaxis(points, 0, -1)

    def finite_depth(self) -> NDArray[np.bool_]:
        """Pixels whose ground point is known (a depth return, or a ray to the ground);
        computed once per capture (every detection in it asks), read-only."""
        cached: NDArray[np.bool_] | None = self.__dict__.get("_finite_depth")
        if cached is None:
            if self.depth_m is not None:
                cached = np.isfinite(self.depth_m)
            else:
                height, width = self.rgb.shape[:2]
                v, u = np.mgrid[0:height, 0:width]
                rays = pixel_rays(self.pose, self.config, u + 0.5, v + 0.5)
                cached = np.asarray(rays[..., 2] < -1e-9)
            cached.flags.writeable = False
            object.__setattr__(self, "_finite_depth", cached)  # a cache, not a field
        return cached


class SensorConfig(StrictModel):
    """The drone's sensors: an RGB camera always; a depth sensor and a semantic camera
    (semantic classes and landmark instances with their categories) when enabled, sharing
    the camera's optics. Runs, their provenance and their tables say which were on."""

    depth: bool = True
    semantic: bool = True
    image_px: int = Field(default=224, ge=32, le=1024)
    fov_deg: float = Field(default=90.0, ge=10.0, le=150.0)
    max_depth_m: float = Field(default=500.0, gt=0.0)
    height_levels: int = Field(default=24, ge=2, le=512, description="ray-march levels")

    @property
    def kinds(self) -> frozenset[SensorKind]:
        kinds: set[SensorKind] = {"rgb"}
        if self.depth:
            kinds.add("depth")
        if self.semantic:
            kinds.add("semantic")
        return frozenset(kinds)

    def camera(self) -> CameraConfig:
        return CameraConfig(
            width_px=self.image_px,
            height_px=self.image_px,
            fov_deg=self.fov_deg,
            max_depth_m=self.max_depth_m,
            height_levels=self.height_levels,
        )

    def describe(self) -> str:
        """How tables and provenance name the sensors, e.g. ``RGB + depth + semantic camera``."""
        names = {"rgb": "RGB", "depth": "depth", "semantic": "semantic camera"}
        return " + ".join(names[k] for k in ("rgb", "depth", "semantic") if k in self.kinds)


class Sensors(Protocol):
    """The agent's handle on the drone's sensors at its current position.

    The drone may turn in place and capture as often as it likes (active perception);
    nothing else is reachable through the handle: images only.
    """

    @property
    def kinds(self) -> frozenset[SensorKind]: ...

    def capture(self, heading_deg: float, pitch_deg: float) -> CameraImages:
        """What the sensors see after turning to compass ``heading_deg``, pitched down."""
        ...

    def capture_many(self, views: Sequence[tuple[float, float]]) -> list[CameraImages]:
        """Several ``(heading_deg, pitch_deg)`` captures from here (rendered as a batch)."""
        ...
