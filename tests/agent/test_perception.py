"""Perception through the sensors: panorama, the simulated detector on real rendered pixels
(labels from categories, captions from measured colours, misses, confusions, phantoms),
localisation with and without depth, merging, roads."""

from __future__ import annotations

import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.agent import Perception, PerceptionConfig, SimulatedDetector, create_detector
from skyvln_eval.agent.detectors import _NAMED_COLOURS, Detection, colour_name, road_bearings
from skyvln_eval.agent.perception import LandmarkTracker
from skyvln_eval.errors import ConfigError, MissingExtraError, PerceptionError, UnknownNameError
from skyvln_eval.frames import ViewPose
from skyvln_eval.sensing import SemanticClass, SensorConfig
from skyvln_eval.sim.sensors import SimulatedSensors
from tests.toy_worlds import flat_world, town_world

CROSSING = ViewPose(300.0, 300.0, 60.0, math.pi / 2)  # above the crossing, heading north
PERFECT = {"miss_rate": 0.0, "false_positive_rate": 0.0, "confusion_rate": 0.0}


def sensors_at(at: ViewPose, world: object = None, **config: object) -> SimulatedSensors:
    return SimulatedSensors(
        world or town_world(),  # type: ignore[arg-type]
        at.x_m,
        at.y_m,
        at.z_m,
        SensorConfig(**config),  # type: ignore[arg-type]
    )


def observe(
    detector: SimulatedDetector, at: ViewPose = CROSSING, sensors: dict[str, object] | None = None
) -> object:
    perception = Perception(PerceptionConfig(), detector)
    perception.reset(seed=1)
    return perception, perception.observe(sensors_at(at, **(sensors or {})), at)


def test_a_panorama_turns_through_the_headings_and_looks_down() -> None:
    _, small = observe(SimulatedDetector(**PERFECT), sensors={"image_px": 64})
    assert all(v.images.rgb.shape == (64, 64, 3) for v in small.views)  # the sensors' camera
    _, panorama = observe(SimulatedDetector(**PERFECT))
    names = [(v.name, v.heading_deg, v.pitch_deg) for v in panorama.views]
    assert names == [
        ("front", 0.0, 60.0),
        ("right", 90.0, 60.0),
        ("back", 180.0, 60.0),
        ("left", 270.0, 60.0),
        ("below", 0.0, 90.0),
    ]


def test_landmarks_are_placed_on_the_ground_once_each_from_their_best_view() -> None:
    _, panorama = observe(SimulatedDetector(**PERFECT))
    by_caption = {s.caption: s for s in panorama.sightings}
    assert len(panorama.sightings) == 3  # each seen in several views, kept once
    # Labels come from the semantic camera's categories, captions from measured colours:
    # never the dataset's description text ("a small restaurant with a red roof").
    assert set(by_caption) == {
        "a restaurant with a red roof",
        "a restaurant with a black roof",
        "a church with a red roof",
    }
    red = by_caption["a restaurant with a red roof"]
    assert red.label == "restaurant"
    # Seen from the side, its wall facing the drone counts too: a few metres of bias.
    assert (red.x_m, red.y_m) == pytest.approx((325.0, 420.0), abs=10.0)
    assert red.distance_m == pytest.approx(math.hypot(red.east_m, red.north_m))
    assert red.distance_m == pytest.approx(math.hypot(25, 120), abs=10.0)
    assert red.bearing_deg == pytest.approx(math.degrees(math.atan2(25, 120)), abs=2.0)
    assert red.size_m == pytest.approx(20.0, abs=4.0)
    assert red.view_name == "front"
    church = by_caption["a church with a red roof"]
    assert church.view_name == "left" and church.label == "church"


def test_without_a_depth_sensor_landmarks_are_placed_where_their_rays_meet_the_ground() -> None:
    _, with_depth = observe(SimulatedDetector(**PERFECT))
    _, without = observe(SimulatedDetector(**PERFECT), sensors={"depth": False})
    assert all(v.images.depth_m is None for v in without.views)  # the channel is not there
    near = {s.caption: (s.x_m, s.y_m) for s in with_depth.sightings}
    far = {s.caption: (s.x_m, s.y_m) for s in without.sightings}
    assert set(far) == set(near)
    for caption, (x, y) in far.items():  # the 8 m roofs are seen a little beyond, not lost
        assert math.hypot(x - near[caption][0], y - near[caption][1]) < 25.0, caption


def test_a_certain_miss_rate_hides_every_landmark_and_confusion_changes_labels() -> None:
    _, panorama = observe(SimulatedDetector(**{**PERFECT, "miss_rate": 1.0}))
    assert panorama.sightings == ()
    _, confused = observe(SimulatedDetector(**{**PERFECT, "confusion_rate": 1.0}), sensors={})
    labels = {s.label for s in confused.sightings}
    assert labels - {"restaurant", "church"}  # some label went wrong on purpose
    assert all(s.label not in ("bridge", "park", "roundabout") for s in confused.sightings)


def test_phantoms_are_consistent_and_vanish_from_close_by() -> None:
    detector = SimulatedDetector(
        **{**PERFECT, "false_positive_rate": 1.0}, close_look_m=70.0, seed=4
    )
    _, far = observe(detector)
    phantoms = [s for s in far.sightings if math.hypot(s.x_m - 230.0, s.y_m - 230.0) < 15.0]
    assert len(phantoms) == 1
    phantom = phantoms[0]
    assert phantom.caption == f"a {phantom.label} with a red roof"  # captioned from its pixels
    assert phantom.label not in ("bridge", "park", "roundabout")
    # Seen again from elsewhere, the same house fools the detector the same way.
    detector.reset(seed=1)
    _, again = observe(detector, at=ViewPose(300.0, 250.0, 60.0, math.pi / 2))
    seen_again = [s for s in again.sightings if math.hypot(s.x_m - 230.0, s.y_m - 230.0) < 15.0]
    assert [s.label for s in seen_again] == [phantom.label]
    # Right above it at 40 m, the detector sees that it is an ordinary house.
    _, close = observe(detector, at=ViewPose(230.0, 230.0, 40.0, math.pi / 2))
    assert all(math.hypot(s.x_m - 230.0, s.y_m - 230.0) > 15.0 for s in close.sightings)


def test_ids_stay_with_their_landmark_from_step_to_step() -> None:
    perception, first = observe(SimulatedDetector(**PERFECT))
    moved = ViewPose(300.0, 360.0, 60.0, math.pi / 2)
    second = perception.observe(sensors_at(moved), moved)
    ids_before = {s.caption: s.landmark_id for s in first.sightings}
    ids_after = {s.caption: s.landmark_id for s in second.sightings}
    assert ids_after == ids_before
    tracker = LandmarkTracker(radius_m=25.0)
    assert tracker.assign("mall", 0, 0, 150.0, set()) == "L1"
    assert tracker.assign("mall", 60, 0, 150.0, set()) == "L1"  # big: its centre wanders
    assert tracker.assign("mall", 60, 0, 150.0, {"L1"}) == "L2"


def test_roads_leaving_from_below_are_found_by_the_detector() -> None:
    _, panorama = observe(SimulatedDetector(**PERFECT))
    assert panorama.road_bearings_deg == pytest.approx((0.0, 90.0, 180.0, 270.0), abs=4.0)
    semantic = np.full((64, 64), SemanticClass.GRASS, np.uint8)
    semantic[:, 28:36] = SemanticClass.ROAD  # straight ahead and behind
    assert road_bearings(semantic, heading_deg=45.0) == pytest.approx((45.0, 225.0), abs=4.0)


def test_the_simulated_detector_needs_the_semantic_camera() -> None:
    detector = SimulatedDetector()
    assert detector.requires == {"rgb", "semantic"}
    rgb_only = sensors_at(CROSSING, semantic=False).capture(0.0, 60.0)
    assert rgb_only.semantic is None and rgb_only.instance is None
    with pytest.raises(PerceptionError, match="grounding_dino"):
        detector.detect(rgb_only)
    on_xview = sensors_at(CROSSING, world=flat_world()).capture(0.0, 60.0)  # no layers
    with pytest.raises(PerceptionError, match="semantic camera"):
        detector.detect(on_xview)
    with pytest.raises(UnknownNameError, match="Did you mean 'simulated'"):
        create_detector("simulate")


def test_colour_names_follow_the_majority_of_pixels() -> None:
    pixels = np.array([[200, 40, 40]] * 8 + [[30, 30, 30]] * 3)
    assert colour_name(pixels) == "red"


def test_colour_names_are_those_of_the_nearest_colour_by_squared_distance() -> None:
    # The direct definition, with ties broken towards the palette's first colour.
    palette = np.array(list(_NAMED_COLOURS.values()), dtype=np.int64)
    names = list(_NAMED_COLOURS)
    rng = np.random.default_rng(5)
    for size in (1, 7, 300):
        for _ in range(100):
            pixels = rng.integers(0, 256, (size, 3))
            distance = ((pixels[:, None, :] - palette[None]) ** 2).sum(axis=2)
            votes = np.bincount(distance.argmin(axis=1), minlength=len(names))
            assert colour_name(pixels.astype(np.uint8)) == names[int(votes.argmax())]
    # Pixels at equal distance from two colours go to the palette's first of them.
    grid = np.stack(np.meshgrid(*[np.arange(0, 256, 3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    distance = ((grid[:, None, :] - palette[None]) ** 2).sum(axis=2)
    ordered = np.sort(distance, axis=1)
    ties = grid[ordered[:, 0] == ordered[:, 1]]
    assert len(ties) > 10
    for pixel in ties:
        assert (
            colour_name(pixel[None].astype(np.uint8))
            == names[int(np.argmin(((pixel[None] - palette) ** 2).sum(axis=1)))]
        )


def test_grounding_dino_without_the_vision_extra_says_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "transformers", None)  # import fails as when not installed
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'skyvln-eval\[vision\]'"):
        create_detector("grounding_dino")


def test_grounding_dino_without_weights_says_where_they_are_looked_for_and_how_to_get_them(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # An audit: "needs the optional 'vision' dependencies ... Check your internet
    # connection ...: pip install" with the extra installed and nothing ever downloaded.
    def no_weights(name: str, **_: object) -> object:
        raise OSError(f"{name} is not in the local cache and local_files_only is set")

    loader = types.SimpleNamespace(from_pretrained=no_weights)
    fake = types.ModuleType("transformers")
    fake.AutoProcessor = loader  # type: ignore[attr-defined]
    fake.AutoModelForZeroShotObjectDetection = loader  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "transformers", fake)
    monkeypatch.setitem(sys.modules, "torch", types.ModuleType("torch"))
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path))
    import huggingface_hub.constants

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path))
    with pytest.raises(ConfigError) as hub:
        create_detector("grounding_dino")
    said = str(hub.value)
    assert "the weights of detector model 'IDEA-Research/grounding-dino-tiny' are not in" in said
    assert "huggingface-cli download IDEA-Research/grounding-dino-tiny" in said
    assert "pip install" not in said and "internet" not in said
    with pytest.raises(ConfigError, match=r"detector model folder \./models/gd does not exist"):
        create_detector("grounding_dino", model="./models/gd")


def test_a_detection_keeps_its_mask_and_box() -> None:
    mask = np.zeros((8, 8), bool)
    mask[2:4, 3:6] = True
    detection = Detection("church", (3, 2, 6, 4), 0.8, "a church", mask)
    assert detection.mask is not None and detection.mask.sum() == 6
