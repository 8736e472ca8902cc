"""The fast renderer (tiled march, batched views) against the reference renderer.

Stated tolerance: in every layer (depth, RGB, semantic, instance) at most 0.1% of the
pixels of a view may differ, and a differing depth by at most 1% (observed on seeded
cities and poses: no pixel differs; the fast march samples the same rays at the same
levels, fewer of them).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.sim.camera import CameraConfig, CameraImages, CameraPose, CameraRig, render_camera
from skyvln_eval.worlds.tile import SemanticClass, WorldTile
from tests.toy_worlds import SIZE, georef, textured

MAX_DIFFERING_SHARE = 1e-3


def seeded_city(seed: int) -> WorldTile:
    """60 flat-roofed blocks of 4 to 150 m (some on the map's edge) over textured ground."""
    rng = np.random.default_rng(seed)
    semantic = np.full((SIZE, SIZE), SemanticClass.GROUND, np.uint8)
    instance = np.zeros((SIZE, SIZE), np.uint16)
    heights = np.zeros((SIZE, SIZE), np.float32)
    for block in range(1, 61):
        row, col = rng.integers(-20, SIZE - 10, size=2)
        rows, cols = rng.integers(8, 90, size=2)
        area = (slice(max(row, 0), row + rows), slice(max(col, 0), col + cols))
        heights[area] = rng.uniform(4.0, 150.0 if block % 10 == 0 else 40.0)
        semantic[area] = SemanticClass.BUILDING
        instance[area] = block
    return WorldTile(f"city{seed}", georef(), textured(seed), semantic, instance, heights)


def differing_share(fast: CameraImages, reference: CameraImages) -> dict[str, float]:
    both = np.isfinite(fast.depth_m) & np.isfinite(reference.depth_m)
    close = np.zeros(fast.depth_m.shape, bool)
    close[both] = np.abs(fast.depth_m[both] - reference.depth_m[both]) <= 0.01 * np.maximum(
        reference.depth_m[both], 1e-6
    )
    close |= np.isinf(fast.depth_m) & np.isinf(reference.depth_m)
    assert fast.semantic is not None and reference.semantic is not None
    assert fast.instance is not None and reference.instance is not None
    return {
        "depth": float(np.mean(fast.depth_m != reference.depth_m)),
        "depth_beyond_1pct": float(np.mean(~close)),
        "rgb": float(np.mean((fast.rgb != reference.rgb).any(axis=2))),
        "semantic": float(np.mean(fast.semantic != reference.semantic)),
        "instance": float(np.mean(fast.instance != reference.instance)),
    }


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_batched_fast_views_match_the_reference_renderer(seed: int) -> None:
    world = seeded_city(seed)
    rng = np.random.default_rng(100 + seed)
    config = CameraConfig(width_px=96, height_px=80)  # small images keep the test quick
    worst: dict[str, float] = {}
    for _ in range(6):
        x, y = rng.uniform(-50.0, 650.0, size=2)  # some positions off the map
        rig = CameraRig(world, float(x), float(y), float(rng.uniform(20.0, 170.0)), config)
        headings = [(float(rng.uniform(-math.pi, math.pi)), float(p)) for p in (0, 20, 45, 60, 90)]
        fast = rig.capture_many(headings)
        for (yaw, pitch), images in zip(headings, fast, strict=True):
            pose = CameraPose(rig.x_m, rig.y_m, rig.z_m, yaw, pitch)
            reference = render_camera(world, pose, config, method="reference")
            for layer, share in differing_share(images, reference).items():
                worst[layer] = max(worst.get(layer, 0.0), share)
    assert all(share <= MAX_DIFFERING_SHARE for share in worst.values()), worst


def test_a_batch_gives_the_views_one_capture_each_gives() -> None:
    world = seeded_city(3)
    rig = CameraRig(world, 300.0, 280.0, 90.0, CameraConfig(width_px=64, height_px=64))
    headings = [(0.3, 60.0), (1.9, 60.0), (0.3, 90.0)]
    batch = rig.capture_many(headings)
    for (yaw, pitch), images in zip(headings, batch, strict=True):
        single = rig.capture(yaw, pitch)
        assert np.array_equal(single.depth_m, images.depth_m)
        assert np.array_equal(single.rgb, images.rgb)
        assert single.pose == images.pose


def test_views_from_different_positions_are_not_a_batch() -> None:
    from skyvln_eval.errors import ConfigError
    from skyvln_eval.sim.camera import render_views

    world = seeded_city(4)
    poses = [CameraPose(10.0, 10.0, 50.0, 0.0, 60.0), CameraPose(11.0, 10.0, 50.0, 0.0, 60.0)]
    with pytest.raises(ConfigError, match="one position"):
        render_views(world, poses)
