"""The simulated sensors: views looked at again are copied from a recent batch, not
rendered again, and every capture owns its arrays."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from skyvln_eval.frames import compass_to_enu_yaw_rad
from skyvln_eval.sensing import CameraPose, SensorConfig
from skyvln_eval.sim import sensors as sensors_module
from skyvln_eval.sim.camera import render_views
from skyvln_eval.sim.sensors import RECENT_RENDERS, SimulatedSensors
from tests.toy_worlds import town_world

VIEWS = [(0.0, 60.0), (90.0, 60.0), (180.0, 60.0), (270.0, 60.0), (0.0, 90.0)]


@pytest.fixture
def renders(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """The number of views each real render call drew, with an empty memo."""
    calls: list[int] = []

    def counting(world: Any, poses: Any, config: Any = None, method: Any = "native") -> Any:
        calls.append(len(poses))
        return render_views(world, poses, config, method)

    monkeypatch.setattr(sensors_module, "render_views", counting)
    RECENT_RENDERS.clear()
    yield calls
    RECENT_RENDERS.clear()


def test_the_same_views_from_the_same_place_are_rendered_once(renders: list[int]) -> None:
    world = town_world()
    config = SensorConfig(image_px=64)
    first = SimulatedSensors(world, 300.0, 330.0, 80.0, config).capture_many(VIEWS)
    again = SimulatedSensors(world, 300.0, 330.0, 80.0, config).capture_many(VIEWS)
    assert renders == [5]
    assert RECENT_RENDERS.hits == 1
    for a, b in zip(first, again, strict=True):
        assert a.pose == b.pose
        assert a.instance_categories == b.instance_categories
        for name in ("rgb", "depth_m", "semantic", "instance"):
            x, y = getattr(a, name), getattr(b, name)
            assert x is not None and y is not None
            np.testing.assert_array_equal(x, y)
            assert not np.shares_memory(x, y), f"{name} is shared between two captures"
    # An agent's images are read-only (the run log keeps its RGB views); one that makes
    # them writable and paints on them still reaches no other capture.
    with pytest.raises(ValueError, match="read-only"):
        first[0].rgb[:] = 0
    first[0].rgb.flags.writeable = True
    first[0].rgb[:] = 0
    third = SimulatedSensors(world, 300.0, 330.0, 80.0, config).capture_many(VIEWS)
    np.testing.assert_array_equal(third[0].rgb, again[0].rgb)
    assert third[0].rgb.any()


def test_another_place_heading_or_camera_is_rendered_anew(renders: list[int]) -> None:
    world = town_world()
    config = SensorConfig(image_px=64)
    SimulatedSensors(world, 300.0, 330.0, 80.0, config).capture_many(VIEWS)
    SimulatedSensors(world, 300.0, 330.5, 80.0, config).capture_many(VIEWS)  # moved
    SimulatedSensors(world, 300.0, 330.0, 80.0, config).capture_many(VIEWS[:4])  # fewer
    SimulatedSensors(world, 300.0, 330.0, 80.0, SensorConfig(image_px=96)).capture_many(VIEWS)
    SimulatedSensors(town_world(), 300.0, 330.0, 80.0, config).capture_many(VIEWS)  # world
    assert renders == [5, 5, 4, 5, 5]
    assert RECENT_RENDERS.hits == 0


def test_the_memo_keeps_only_the_most_recent_batches(renders: list[int]) -> None:
    world = town_world()
    config = SensorConfig(image_px=32)
    places = [(200.0 + 5.0 * k, 300.0, 80.0) for k in range(RECENT_RENDERS.size + 1)]
    for x, y, z in places:
        SimulatedSensors(world, x, y, z, config).capture(0.0, 60.0)
    SimulatedSensors(world, *places[-1], config).capture(0.0, 60.0)  # recent: a hit
    SimulatedSensors(world, *places[0], config).capture(0.0, 60.0)  # evicted: rendered
    assert len(renders) == RECENT_RENDERS.size + 2
    assert RECENT_RENDERS.hits == 1


def test_instances_are_numbered_per_capture_not_by_the_worlds_ids() -> None:
    """The semantic camera tells instances apart in one image; the numbers are the
    capture's own (1, 2, ... in the order of the world's ids), so they do not say which
    landmark of the map an instance is, and each keeps its pixels and category."""
    world = town_world()
    config = SensorConfig(image_px=96)
    views = [(0.0, 90.0)]
    seen_ids: list[list[int]] = []
    for x, y in ((325.0, 420.0), (420.0, 325.0), (180.0, 330.0)):  # over each landmark
        sensors = SimulatedSensors(world, x, y, 150.0, config)
        pose = CameraPose(x, y, 150.0, compass_to_enu_yaw_rad(0.0), 90.0)
        [raw] = render_views(world, [pose], config.camera())
        [image] = sensors.capture_many(views)
        assert image.instance is not None and raw.instance is not None
        world_ids = sorted(set(np.unique(raw.instance).tolist()) - {0})
        numbers = sorted(set(np.unique(image.instance).tolist()) - {0})
        assert world_ids and numbers == list(range(1, len(world_ids) + 1))
        for number, world_id in enumerate(world_ids, start=1):
            np.testing.assert_array_equal(image.instance == number, raw.instance == world_id)
            assert image.instance_categories[number] == world.landmark(world_id).category
        seen_ids.append(world_ids)
    # Three different landmarks below, one number for all of them.
    assert len({tuple(ids) for ids in seen_ids}) == 3
