"""The simulated detector against its algorithm before it was vectorised
(:mod:`tests.agent.detector_reference`): on panoramas rendered from the synthetic sample's
worlds, with phantoms on, it must find the same detections (labels, boxes, scores,
captions, masks) and draw the same random numbers; and the exact stand-ins it uses for
np.median, math.hypot scans and the colour's matrix product agree with them bit for bit."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skyvln_eval.agent import Perception, PerceptionConfig, SimulatedDetector
from skyvln_eval.agent.base import episode_key, episode_seed
from skyvln_eval.agent.detectors import (
    _NAMED_COLOURS,
    _PALETTE,
    _KnownBuildings,
    _nearest_colours,
    _nearest_colours_by_box,
    colour_name,
)
from skyvln_eval.avdn import load_split
from skyvln_eval.frames import view_to_pose
from skyvln_eval.sensing import CameraImages, SensorConfig, instance_pixel_counts
from skyvln_eval.sim.sensors import SimulatedSensors
from skyvln_eval.worlds import load_world
from tests.agent.detector_reference import ReferenceDetector


def reference_colour(rgb: np.ndarray) -> str:
    """The nearest named colour by squared distance, the majority over pixels."""
    palette = _PALETTE.astype(np.int64)
    distance = ((rgb.reshape(-1, 1, 3).astype(np.int64) - palette[None]) ** 2).sum(axis=2)
    votes = np.bincount(distance.argmin(axis=1), minlength=len(palette))
    return list(_NAMED_COLOURS)[int(votes.argmax())]


Episodes = list[tuple[int, list[CameraImages]]]


@pytest.fixture(scope="module")
def panoramas(sample_dir: Path) -> dict[bool, Episodes]:
    """Each of a few val_seen episodes' seed and the views of the panoramas from its first
    ground-truth views, rendered with depth and without."""
    perception = Perception(PerceptionConfig(), SimulatedDetector())
    episodes = load_split(sample_dir, "val_seen").episodes("andh")[:3]
    rendered: dict[bool, Episodes] = {True: [], False: []}
    for episode in episodes:
        world = load_world(sample_dir, episode.map_name, episode.georef)
        for depth, out in rendered.items():
            views = []
            for corners in episode.gt_path_corners[:4]:
                pose = view_to_pose(corners, episode.georef)
                config = SensorConfig(depth=depth)
                sensors = SimulatedSensors(world, pose.x_m, pose.y_m, pose.z_m, config)
                views += [view.images for view in perception.capture(sensors, pose)]
            out.append((episode_seed(0, episode_key(episode.episode_id)), views))
    return rendered


@pytest.mark.parametrize("depth", [True, False])
@pytest.mark.parametrize(
    "settings",
    [
        {"false_positive_rate": 0.03},
        {"false_positive_rate": 0.5, "miss_rate": 0.3, "confusion_rate": 0.3, "seed": 4},
        {"false_positive_rate": 1.0, "close_look_m": 40.0, "phantom_cell_m": 60.0},
        {"false_positive_rate": 0.3, "min_pixels": 5, "phantom_cell_m": 10.0},
    ],
)
def test_the_detector_finds_what_the_plain_algorithm_finds_and_draws_alike(
    panoramas: dict[bool, Episodes], depth: bool, settings: dict[str, Any]
) -> None:
    new, old = SimulatedDetector(**settings), ReferenceDetector(**settings)
    phantoms = 0
    for seed, views in panoramas[depth]:
        new.reset(seed)
        old.reset(seed)
        for images in views:
            found, expected = new.detect(images), old.detect(images)
            assert [(d.label, d.box_px, d.score, d.caption) for d in found] == [
                (d.label, d.box_px, d.score, d.caption) for d in expected
            ]
            for a, b in zip(found, expected, strict=True):
                assert a.mask is not None and b.mask is not None
                assert a.mask.dtype == bool and np.array_equal(a.mask, b.mask)
            assert new._rng.bit_generator.state == old.rng.bit_generator.state
            assert images.instance is not None
            phantoms += sum(not images.instance[d.mask].any() for d in found)  # no landmark's
        assert new._buildings.decisions == [decision for _, _, decision in old.buildings]
        # and placed every building met at the very same point
        met = np.array([(x, y) for x, y, _ in old.buildings]).reshape(-1, 2)
        assert new._buildings._xy[: len(met)].tobytes() == met.tobytes()
    if settings["false_positive_rate"] >= 0.3:
        assert phantoms > 0  # the phantom path was exercised


def test_known_buildings_are_found_as_a_hypot_scan_finds_them() -> None:
    # Places within an ulp or so of the radius, where squared distances and math.hypot
    # can round to different sides.
    rng = np.random.default_rng(8)
    radius = 30.0
    known = _KnownBuildings()
    met: list[tuple[float, float]] = []
    for _ in range(300):
        angle, x0, y0 = rng.uniform(0, 2 * math.pi), rng.uniform(-500, 500), rng.uniform(-500, 500)
        x, y = x0 + radius * math.cos(angle), y0 + radius * math.sin(angle)
        for _ in range(int(rng.integers(0, 3))):
            x = math.nextafter(x, math.inf if rng.random() < 0.5 else -math.inf)
        known.add(x, y, None)
        met.append((x, y))
        places = [(x0, y0), (x, y), (math.nan, y0), *rng.uniform(-500, 500, (3, 2)).tolist()]
        scanned = [
            next(
                (i for i, (bx, by) in enumerate(met) if math.hypot(bx - px, by - py) <= radius),
                None,
            )
            for px, py in places
        ]
        assert known.first_within(places, radius) == scanned
        assert [known.first_within_since(0, px, py, radius) for px, py in places] == scanned


def test_camera_pixels_get_the_colour_the_float_path_gives() -> None:
    # Every pixel on a grid through the colour cube (ties included), one by one: the
    # integer keys of uint8 pixels pick the colour the float matrix product picks.
    grid = np.stack(np.meshgrid(*[np.arange(0, 256, 3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    floats = grid.astype(np.float64) @ (-2.0 * _PALETTE.T) + (_PALETTE**2).sum(axis=1)
    assert np.array_equal(_nearest_colours(grid.astype(np.uint8)), floats.argmin(axis=1))
    rng = np.random.default_rng(2)
    for size in (1, 5, 300, 5000):
        pixels = rng.integers(0, 256, (size, 3))
        assert (
            colour_name(pixels.astype(np.uint8)) == colour_name(pixels) == reference_colour(pixels)
        )


def test_colours_read_by_box_are_the_computed_ones_for_every_24_bit_colour() -> None:
    """The box table (a box's colour known from its corners) against the computation, for
    all 2**24 colours: ties included, no box is taken for pure that is not."""
    every = np.arange(1 << 24, dtype=np.uint32)
    for start in range(0, 1 << 24, 1 << 21):
        colours = every[start : start + (1 << 21)]
        rgb = np.stack([colours >> 16, (colours >> 8) & 255, colours & 255], axis=-1)
        rgb = rgb.astype(np.uint8)
        assert np.array_equal(_nearest_colours_by_box(rgb), _nearest_colours(rgb)), start


def test_instance_pixel_counts_are_numpys_unique_counts() -> None:
    rng = np.random.default_rng(11)
    images = [
        np.zeros((8, 8), np.uint16),
        np.full((8, 8), 65535, np.uint16),
        *(
            (rng.integers(0, 3, (64, 64)) * rng.integers(0, 400, (64, 64))).astype(np.uint16)
            for _ in range(20)
        ),
    ]
    for instance in images:
        ids, counts = instance_pixel_counts(instance)
        expected_ids, expected_counts = np.unique(instance, return_counts=True)
        assert ids.tolist() == expected_ids.tolist()
        assert counts.tolist() == expected_counts.tolist()
