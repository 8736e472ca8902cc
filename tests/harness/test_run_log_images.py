"""Run logs encode each distinct image once: a view seen again, or the same pixels captured
again, is not re-encoded."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.agent.actions import Move, Turn
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import read_log
from skyvln_eval.harness import run_log
from skyvln_eval.harness.run_log import RunLogContent, Step
from tests.toy_worlds import town_episode, town_world


def test_a_repeated_view_is_encoded_once_and_logged_at_every_step(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    episode = town_episode("fly to the red restaurant")
    world = town_world()
    start, moved = (np.asarray(c, dtype=np.float64) for c in episode.gt_path_corners[:2])
    encoded: list[int] = []
    real = run_log.encode_image

    def counting(image: np.ndarray, image_format: str, quality: int) -> bytes:
        encoded.append(1)
        return real(image, image_format, quality)  # type: ignore[arg-type]

    monkeypatch.setattr(run_log, "encode_image", counting)
    # The second step was cancelled (the view did not change), the third moved.
    views = [start, start, moved]
    steps = [
        Step(float(k), k, view, "", action, None, {})
        for k, (view, action) in enumerate(
            zip(views, [Turn(90.0), Move("forward", 50.0), Move("forward", 50.0)], strict=True)
        )
    ]
    content = RunLogContent(steps, views, [0.0, 1.0, 2.0])
    path = tmp_path / "run.mcap"
    run_log.write_run_log(path, episode, world, content)
    assert len(encoded) == 2
    images = [m.decode()["data"] for m in read_log(path).topic(t.TOPIC_OBSERVATION)]
    assert len(images) == 3
    assert images[0] == images[1] != images[2]


def test_the_same_captured_pixels_are_encoded_once_and_logged_at_every_capture(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    episode = town_episode("fly to the red restaurant")
    start = np.asarray(episode.gt_path_corners[0], dtype=np.float64)
    rng = np.random.default_rng(0)
    seen, other = (rng.integers(0, 256, (32, 48, 3), dtype=np.uint8) for _ in range(2))
    encoded: list[bytes] = []
    real = run_log.encode_image

    def counting(image: np.ndarray, image_format: str, quality: int) -> bytes:
        encoded.append(np.ascontiguousarray(image).tobytes())
        return real(image, image_format, quality)  # type: ignore[arg-type]

    monkeypatch.setattr(run_log, "encode_image", counting)
    # The agent looks the same way twice at the first step and again at the second (a
    # copy of the pixels, not the same array), then somewhere else.
    captures = [
        [("front", seen), ("again", seen.copy())],
        [("front", seen.copy()), ("down", other)],
    ]
    steps = [
        Step(float(k), k, start, "", Turn(90.0), None, {}, camera_views=views)
        for k, views in enumerate(captures)
    ]
    path = tmp_path / "run.mcap"
    run_log.write_run_log(path, episode, None, RunLogContent(steps, [start], [0.0]))
    assert sorted(encoded) == sorted([seen[..., ::-1].tobytes(), other[..., ::-1].tobytes()])
    logged = [m.decode() for m in read_log(path).topic(t.TOPIC_CAMERA_VIEWS)]
    assert [m["frame_id"].rsplit("/", 1)[-1] for m in logged] == ["front", "again", "front", "down"]
    jpeg = real(seen[..., ::-1], "jpeg", run_log.DEFAULT_OPTIONS.jpeg_quality)
    assert base64.b64decode(logged[0]["data"]) == jpeg
    assert logged[0]["data"] == logged[1]["data"] == logged[2]["data"] != logged[3]["data"]
