"""The metric local frame: east-north-up metres from a map's south-west corner.

Simulation, control and logs work in ENU metres: x east and y north from the map's
``gps_botm_left``, using the same flat 111,300 m per degree as the official geometry (so
a view that AVDN calls square is square here too), z the height above ground. Yaw is the
compass heading (0 = north, clockwise, degrees) converted to ENU radians (0 = east,
counter-clockwise) by :func:`compass_to_enu_yaw_rad` and back, nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.geometry import view_centre, view_edge_m, view_from_pose, view_heading_deg
from skyvln_eval.avdn.imagery import MapGeoref


def compass_to_enu_yaw_rad(heading_deg: Any) -> Any:
    """Compass heading (deg, 0 = north, clockwise) to ENU yaw (rad, 0 = east, CCW), in (-pi, pi]."""
    yaw = np.radians(90.0 - np.asarray(heading_deg, dtype=np.float64))
    wrapped = np.pi - np.mod(np.pi - yaw, 2.0 * np.pi)
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def enu_yaw_to_compass_deg(yaw_rad: Any) -> Any:
    """ENU yaw (rad) to compass heading (deg) in [0, 360)."""
    heading = (90.0 - np.degrees(np.asarray(yaw_rad, dtype=np.float64))) % 360.0
    return float(heading) if heading.ndim == 0 else heading


def latlng_to_enu(points: ArrayLike, georef: MapGeoref) -> NDArray[np.float64]:
    """``[lat, lng]`` points to ENU ``[x_m, y_m]`` from the map's south-west corner."""
    p = np.asarray(points, dtype=np.float64)
    lat0, lng0 = georef.gps_botm_left
    return np.stack(
        [(p[..., 1] - lng0) * METERS_PER_DEGREE, (p[..., 0] - lat0) * METERS_PER_DEGREE], axis=-1
    )


def enu_to_latlng(points: ArrayLike, georef: MapGeoref) -> NDArray[np.float64]:
    """ENU ``[x_m, y_m]`` back to ``[lat, lng]``."""
    p = np.asarray(points, dtype=np.float64)
    lat0, lng0 = georef.gps_botm_left
    return np.stack(
        [lat0 + p[..., 1] / METERS_PER_DEGREE, lng0 + p[..., 0] / METERS_PER_DEGREE], axis=-1
    )


@dataclass(frozen=True)
class ViewPose:
    """A drone pose that sees a view with a 90 degree camera looking straight down.

    ``z_m`` is the height above ground: a 90 degree downward camera at height h sees a
    square of edge 2 h, so an AVDN "altitude" (view edge) of 40-400 m is 20-200 m of flight.
    """

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float

    @property
    def edge_m(self) -> float:
        return 2.0 * self.z_m

    @property
    def heading_deg(self) -> float:
        return float(enu_yaw_to_compass_deg(self.yaw_rad))


def view_to_pose(corners: ArrayLike, georef: MapGeoref) -> ViewPose:
    """The pose from which a downward 90 degree camera sees this view (official heading)."""
    x, y = latlng_to_enu(view_centre(corners), georef)
    heading = float(view_heading_deg(corners))
    return ViewPose(
        float(x), float(y), float(view_edge_m(corners)) / 2.0, compass_to_enu_yaw_rad(heading)
    )


def pose_to_view(pose: ViewPose, georef: MapGeoref) -> NDArray[np.float64]:
    """The square view seen from a pose: centre below the drone, edge 2 z, front along yaw."""
    centre = enu_to_latlng([pose.x_m, pose.y_m], georef)
    return view_from_pose(centre, pose.heading_deg, pose.edge_m)


def wrap_angle_rad(angle: float) -> float:
    """An angle wrapped to (-pi, pi]."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)
