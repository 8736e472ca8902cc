"""ENU frame and compass <-> yaw conversions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.avdn import MapGeoref, hull_iou, view_from_pose
from skyvln_eval.frames import (
    compass_to_enu_yaw_rad,
    enu_to_latlng,
    enu_yaw_to_compass_deg,
    latlng_to_enu,
    pose_to_view,
    view_to_pose,
)

GEOREF = MapGeoref((30.0, 40.0), (30.01, 40.01), 1e-5, 1e-5)


@pytest.mark.parametrize(
    ("compass", "yaw"), [(0, math.pi / 2), (90, 0.0), (180, -math.pi / 2), (270, math.pi)]
)
def test_compass_and_yaw(compass: float, yaw: float) -> None:
    assert compass_to_enu_yaw_rad(compass) == pytest.approx(yaw)
    assert enu_yaw_to_compass_deg(yaw) == pytest.approx(compass % 360)


def test_enu_is_flat_metres_from_the_south_west_corner() -> None:
    xy = latlng_to_enu([30.001, 40.002], GEOREF)
    assert np.allclose(xy, [222.6, 111.3])
    assert np.allclose(enu_to_latlng(xy, GEOREF), [30.001, 40.002])


def test_view_pose_round_trip() -> None:
    view = view_from_pose((30.005, 40.004), 123.0, 180.0)
    pose = view_to_pose(view, GEOREF)
    assert pose.z_m == pytest.approx(90.0)
    assert pose.heading_deg == pytest.approx(123.0, abs=0.06)  # official 1.57 heading
    assert hull_iou(pose_to_view(pose, GEOREF), view) > 0.999
