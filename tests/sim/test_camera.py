"""The front camera: geometry against the official view, depth, layers, occlusion, turning."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.avdn import observe_view
from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import ViewPose, latlng_to_enu, pose_to_view
from skyvln_eval.sensing import CameraImages, camera_basis, plane_coordinates
from skyvln_eval.sim.camera import (
    SEMANTIC_NONE,
    SKY_BGR,
    CameraConfig,
    CameraPose,
    CameraRig,
    pixel_rays,
    render_camera,
)
from skyvln_eval.worlds.tile import SemanticClass
from tests.toy_worlds import flat_world, tower_world


def test_looking_straight_down_sees_the_official_view() -> None:
    world = flat_world()
    pose = ViewPose(300.0, 300.0, 60.0, math.radians(30.0))
    view = pose_to_view(pose, world.georef)
    camera = CameraPose(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad, 90.0)
    config = CameraConfig()
    # The ray through the image's top-left corner hits the view's front-left corner.
    ray = pixel_rays(camera, config, np.array(0.0), np.array(0.0))
    hit = np.array([pose.x_m, pose.y_m]) + ray[:2] * pose.z_m / -ray[2]
    assert np.allclose(hit, latlng_to_enu(view[0], world.georef), atol=1e-6)
    images = render_camera(world, camera, config)
    official = observe_view(world.bgr, view, world.georef)[..., ::-1]
    correlation = np.corrcoef(images.rgb.ravel().astype(float), official.ravel().astype(float))[
        0, 1
    ]
    assert correlation > 0.9
    assert images.semantic is None and images.instance is None  # an image-only map


def test_depth_on_flat_ground_comes_from_the_altitude() -> None:
    world = flat_world()
    down = render_camera(world, CameraPose(300.0, 300.0, 80.0, 0.0, 90.0))
    assert np.allclose(down.depth_m, 80.0, atol=1e-3)
    pitched = render_camera(world, CameraPose(300.0, 300.0, 80.0, 0.0, 60.0))
    centre = pitched.depth_m[112, 112]  # pixel centre just below the optical axis
    assert centre == pytest.approx(80.0 / math.sin(math.radians(60.0)), rel=0.02)
    point = pitched.points_enu(np.array([112]), np.array([112]))[0]
    assert point[2] == pytest.approx(0.0, abs=0.05)


@pytest.mark.parametrize("with_depth", [True, False])
def test_points_are_the_pixel_rays_scaled_by_depth_bit_for_bit(with_depth: bool) -> None:
    """points_enu works one component at a time; its floats are those of the plain
    ``origin + depth * (forward + a right - b up)`` (and, without depth, of the rays'
    meeting with the ground), at every pitch, for points in any array shape."""
    rng = np.random.default_rng(7)
    config = CameraConfig()
    for pitch in (0.0, 30.0, 60.0, 90.0, 47.3):
        pose = CameraPose(-120.5, 310.25, 75.0, 2.2, pitch)
        depth = rng.uniform(0.0, 600.0, (224, 224)).astype(np.float32)
        depth[rng.random((224, 224)) < 0.1] = np.inf
        images = CameraImages(pose, config, np.zeros((224, 224, 3), np.uint8))
        if with_depth:
            images = CameraImages(pose, config, images.rgb, depth)
        for shape in ((), (500,), (7, 9)):
            u, v = rng.integers(0, 224, shape), rng.integers(0, 224, shape)
            # The plain expressions, with no component-wise work: the reference.
            forward, right, up = camera_basis(pose)
            a, b = plane_coordinates(config, u + 0.5, v + 0.5)
            rays = forward + a[..., None] * right - b[..., None] * up
            origin = np.array([pose.x_m, pose.y_m, pose.z_m])
            if with_depth:
                along = depth[v, u].astype(np.float64)
            else:
                down = rays[..., 2] < -1e-9
                along = np.where(down, -origin[2] / np.where(down, rays[..., 2], -1.0), np.inf)
            expected = origin + along[..., None] * rays
            points = images.points_enu(u, v)
            assert points.shape == expected.shape
            assert np.ascontiguousarray(points).tobytes() == expected.tobytes()


def test_rays_above_the_horizon_see_sky_and_get_no_depth() -> None:
    images = render_camera(tower_world(), CameraPose(300.0, 100.0, 50.0, 0.0, 0.0))
    top = images.depth_m[:50]
    assert np.isinf(top).all()
    assert tuple(int(c) for c in images.rgb[10, 10][::-1]) == SKY_BGR
    assert images.semantic is not None and (images.semantic[:50] == SEMANTIC_NONE).all()


def test_a_roof_is_closer_than_the_ground_and_carries_its_landmark_id() -> None:
    world = tower_world(height_m=60.0)
    images = render_camera(world, CameraPose(300.0, 300.0, 100.0, 0.0, 90.0))
    assert images.instance is not None and images.semantic is not None
    assert images.instance[112, 112] == 7
    assert images.semantic[112, 112] == SemanticClass.BUILDING
    assert images.depth_m[112, 112] == pytest.approx(40.0, abs=0.5)
    assert images.depth_m[2, 2] == pytest.approx(100.0, abs=0.5)


def test_a_tall_building_hides_the_ground_behind_it() -> None:
    world = tower_world(height_m=120.0)
    # 150 m south of the tower looking north and a little down: the tower fills the middle.
    # Grazing rays need fine height levels to meet a wall (see CameraConfig.height_levels).
    config = CameraConfig(height_levels=240)
    images = render_camera(world, CameraPose(300.0, 150.0, 60.0, math.pi / 2, 20.0), config)
    assert images.instance is not None
    column = images.instance[:, 112]
    assert (column == 7).sum() > 20
    # The pixel that sees the tower would otherwise reach the ground far beyond it.
    v = int(np.nonzero(column == 7)[0].min())
    assert images.depth_m[v, 112] < 160.0


def test_turning_in_place_rotates_the_view() -> None:
    rig = CameraRig(flat_world(), 300.0, 300.0, 60.0, CameraConfig(width_px=64, height_px=64))
    north = rig.capture(math.pi / 2, 90.0)
    east = rig.capture(0.0, 90.0)
    # Heading east, north is on the left: the north-up image turned clockwise by 90 degrees.
    assert np.abs(np.rot90(north.rgb, k=1).astype(int) - east.rgb.astype(int)).mean() < 8.0


def test_bad_camera_settings_are_rejected() -> None:
    with pytest.raises(ConfigError, match="pitch_deg"):
        CameraPose(0.0, 0.0, 50.0, 0.0, 120.0)
    with pytest.raises(ConfigError, match="above ground"):
        CameraPose(0.0, 0.0, -1.0, 0.0, 90.0)
    with pytest.raises(ConfigError, match="fov_deg"):
        CameraConfig(fov_deg=200.0)


def test_the_four_channel_map_gives_the_three_channel_lookup() -> None:
    """Views look the map up in a four-channel copy (OpenCV vectorises that case): the
    same values as the three-channel image at any sub-pixel point, on and off the map."""
    from skyvln_eval.sim.camera import _bgra
    from skyvln_eval.sim.march import sample_layer

    world = flat_world()
    rng = np.random.default_rng(3)
    height, width = world.shape
    px = rng.uniform(-3.0, width + 3.0, (64, 256)).astype(np.float32)
    py = rng.uniform(-3.0, height + 3.0, (64, 256)).astype(np.float32)
    four = sample_layer(_bgra(world), px, py, nearest=False, fill=0.0)
    three = sample_layer(world.bgr, px, py, nearest=False, fill=0.0)
    assert np.array_equal(four[..., :3], three)
