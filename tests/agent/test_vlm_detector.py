"""The VLM detector against the loopback OpenAI-compatible server: the rendered view arrives
as a decodable JPEG, the answer's boxes become pixel detections (and landmarks on the
ground), malformed answers are refused with reasons, repaired and recorded."""

from __future__ import annotations

import json
import math
from typing import Any

import jsonschema
import pytest

from skyvln_eval.agent import Perception, PerceptionConfig
from skyvln_eval.agent.config import DetectorConfig
from skyvln_eval.agent.detectors import box_of
from skyvln_eval.agent.vlm_detector import (
    BOX_SCALE,
    VlmDetector,
    landmarks_schema,
    parse_landmarks,
)
from skyvln_eval.errors import ActionParseError, ConfigError
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm.loopback import LoopbackOpenAIServer, answer
from skyvln_eval.sensing import CameraImages, SensorConfig
from skyvln_eval.sim.sensors import SimulatedSensors
from tests.toy_worlds import town_world

CROSSING = ViewPose(300.0, 300.0, 60.0, math.pi / 2)  # above the crossing, heading north
RGB_ONLY = SensorConfig(depth=False, semantic=False)


def vlm(base_url: str, **settings: Any) -> LLMConfig:
    options: dict[str, Any] = {"takes_images": True, "image_max_side_px": 128, "repairs": 0}
    return LLMConfig(backend="openai:vlm-test", base_url=base_url, **(options | settings))


def landmarks(*items: tuple[str, list[float], float, str]) -> str:
    keys = ("label", "box", "score", "caption")
    return json.dumps({"landmarks": [dict(zip(keys, item, strict=True)) for item in items]})


def capture(config: SensorConfig = RGB_ONLY, heading_deg: float = 0.0) -> CameraImages:
    sensors = SimulatedSensors(town_world(), 300.0, 300.0, 60.0, config)
    return sensors.capture(heading_deg, 60.0)


def test_the_view_arrives_as_an_image_and_boxes_come_back_in_pixels() -> None:
    view = capture()
    width, height = view.size_px  # 224 x 224, sent scaled down to 128
    reply = landmarks(
        ("red restaurant", [100, 250, 300, 500], 0.9, "a building with a red roof"),
        ("Church", [0, 900, 1000, 1000], 0.4, ""),
    )
    with LoopbackOpenAIServer([answer(reply)]) as server:
        detector = DetectorConfig(name="vlm", llm=vlm(server.base_url)).build(seed=0)
        found = detector.detect(view, ["red restaurant", "church"])
        [request] = server.requests
    [image] = request["images"]
    assert image["error"] is None and image["mime_type"] == "image/jpeg"
    assert image["shape"] == [128, 128, 3]  # decodable, and within the size cap
    body = request["body"]
    schema = body["response_format"]["json_schema"]["schema"]
    label = schema["properties"]["landmarks"]["items"]["properties"]["label"]
    assert label["enum"] == ["red restaurant", "church"]  # a constrained decoder keeps to them
    prompt = body["messages"][-1]["content"][0]["text"]
    assert "- red restaurant" in prompt and f"0 to {BOX_SCALE}" in prompt
    assert [(d.label, d.box_px, d.score, d.caption) for d in found] == [
        ("red restaurant", (22, 56, 68, 112), 0.9, "a building with a red roof"),
        ("church", (0, 201, 224, 224), 0.4, "church"),  # the phrase as asked; no caption
    ]
    assert all(d.mask is None for d in found) and width == height == 224
    calls = detector.take_calls()  # type: ignore[attr-defined]
    [record] = calls.records
    assert record.module == "detect" and record.outcome == "ok"
    assert record.structured_output == "json_schema"
    [exchange] = calls.exchanges
    assert exchange["prompt"][-1]["images"] == ["capture (facing 0 deg, 60 deg down)"]
    assert calls.failures == [] and detector.take_calls().records == []  # type: ignore[attr-defined]


def test_boxes_from_the_vlm_place_landmarks_on_the_ground() -> None:
    """The front view's true box of the red restaurant, answered in 0-1000 coordinates,
    becomes a sighting where the restaurant stands (RGB only: rays to flat ground)."""
    truth = capture(SensorConfig(depth=False), heading_deg=0.0)
    assert truth.instance is not None
    width, height = truth.size_px
    x0, y0, x1, y1 = box_of(truth.instance == 1)  # landmark 1: the red restaurant
    box = [x0 * 1000 / width, y0 * 1000 / height, x1 * 1000 / width, y1 * 1000 / height]
    front = landmarks(("red restaurant", box, 0.8, "a red roof"))
    others = [answer(landmarks())] * 4  # right, back, left and straight down: nothing
    with LoopbackOpenAIServer([answer(front), *others]) as server:
        detector = VlmDetector(vlm(server.base_url))
        perception = Perception(PerceptionConfig(), detector)
        perception.reset(seed=1)
        sensors = SimulatedSensors(town_world(), CROSSING.x_m, CROSSING.y_m, 60.0, RGB_ONLY)
        panorama = perception.observe(sensors, CROSSING, ["red restaurant"])
        assert len(server.requests) == 5  # one call per view
        assert all(len(r["images"]) == 1 for r in server.requests)
    [seen] = panorama.sightings
    assert seen.label == "red restaurant" and seen.view_name == "front"
    assert seen.caption == "a red roof"
    assert math.hypot(seen.x_m - 325.0, seen.y_m - 420.0) < 25.0  # where it stands
    assert len(detector.take_calls().records) == 5


def test_malformed_answers_are_refused_repaired_and_recorded() -> None:
    view = capture()
    bad_label = landmarks(("castle", [0, 0, 10, 10], 0.5, ""))
    good = landmarks(("church", [500, 500, 750, 1000], 0.7, "a church"))
    with LoopbackOpenAIServer([answer("I see a church."), answer(good)]) as server:
        detector = VlmDetector(vlm(server.base_url, repairs=1))
        [found] = detector.detect(view, ["church"])
        repaired = server.requests[1]["body"]["messages"]
    assert found.box_px == (112, 112, 168, 224)
    assert "not a JSON object" in repaired[-1]["content"]  # the parser's reason went back
    calls = detector.take_calls()
    assert [r.outcome for r in calls.records] == ["invalid", "ok"] and not calls.failures
    with LoopbackOpenAIServer([answer(bad_label), answer("{}")]) as server:
        detector = VlmDetector(vlm(server.base_url, repairs=1))
        assert detector.detect(view, ["church"]) == []  # nothing usable: nothing seen
    calls = detector.take_calls()
    assert [r.outcome for r in calls.records] == ["invalid", "invalid"]
    [failure] = calls.failures
    assert failure.module == "detect" and failure.substitute == "no detections in this view"
    assert "exactly one field, landmarks" in failure.reason


@pytest.mark.parametrize(
    ("item", "reason"),
    [
        ({"label": "castle"}, "not one of the phrases asked for"),
        ({"box": [0, 0, 10]}, "list of 4 numbers"),
        ({"box": [0, 0, True, 10]}, "list of 4 numbers"),
        ({"box": [0, 0, 10, 1001]}, "must be in [0, 1000]"),
        ({"box": [50, 0, 10, 10]}, "x0 < x1 and y0 < y1"),
        ({"score": 1.5}, "score must be a number in [0, 1]"),
        ({"caption": 7}, "caption must be a string"),
        ({"colour": "red"}, "unknown: colour"),
    ],
)
def test_the_parser_refuses_what_the_schema_refuses_with_a_reason(
    item: dict[str, Any], reason: str
) -> None:
    phrases = ["church"]
    good = {"label": "church", "box": [10, 20, 30, 40], "score": 0.5, "caption": "a church"}
    text = json.dumps({"landmarks": [good | item]})
    with pytest.raises(ActionParseError, match=reason.replace("[", r"\[").replace("]", r"\]")):
        parse_landmarks(text, phrases)
    schema = landmarks_schema(phrases)
    degenerate = item == {"box": [50, 0, 10, 10]}  # the one the schema cannot express
    assert jsonschema.Draft202012Validator(schema).is_valid(json.loads(text)) is degenerate
    jsonschema.validate({"landmarks": [good]}, schema)  # what is accepted, the schema allows
    [mark] = parse_landmarks(json.dumps({"landmarks": [good]}), phrases)
    assert mark.box == (10.0, 20.0, 30.0, 40.0)


def test_without_phrases_the_model_names_what_it_sees() -> None:
    reply = landmarks(("white water tower", [0, 0, 500, 500], 0.6, "a tall white tower"))
    with LoopbackOpenAIServer([answer(reply)]) as server:
        detector = VlmDetector(vlm(server.base_url))
        [found] = detector.detect(capture(), [])
        prompt = server.requests[0]["body"]["messages"][-1]["content"][0]["text"]
    assert found.label == "white water tower" and found.box_px == (0, 0, 112, 112)
    assert "navigate by" in prompt


def test_a_backend_that_takes_no_images_is_refused_with_what_to_change() -> None:
    with pytest.raises(ConfigError, match="takes_images: true"):
        DetectorConfig(name="vlm", llm=LLMConfig(backend="rule")).build(seed=0)
    with pytest.raises(ConfigError, match="does not take images"):
        VlmDetector(vlm("http://127.0.0.1:9/v1", takes_images=False))
    with pytest.raises(ConfigError, match="needs llm"):
        DetectorConfig(name="vlm").build(seed=0)
    assert VlmDetector.requires == {"rgb"}


def test_the_agent_counts_its_detectors_calls_with_its_own() -> None:
    from skyvln_eval.agent import AgentConfig, build_agent
    from skyvln_eval.harness import run_official_episode
    from tests.toy_worlds import town_episode

    empty = json.dumps({"landmarks": []})
    with LoopbackOpenAIServer([answer(empty)] * 40) as server:
        vlm = LLMConfig(
            backend="openai:vlm", base_url=server.base_url, takes_images=True, timeout_s=5.0
        )
        config = AgentConfig.model_validate(
            {"name": "navgpt", "detector": {"name": "vlm", "llm": vlm.model_dump()}}
        )
        rollout = run_official_episode(
            build_agent(config),
            town_episode("Go north."),
            town_world(),
            max_steps=2,
            sensors=SensorConfig(semantic=False),
        )
    detect = [c for c in rollout.llm_calls if c.module == "detect"]
    assert len(detect) == 5  # one call per view of the panorama, in the episode's records
    assert {e["module"] for e in rollout.traces[0]["exchanges"]} >= {"detect"}
