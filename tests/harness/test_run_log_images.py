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
from skyvln_eval.harness.run_log import RunLogContent, Step, camera_view_tf
from skyvln_eval.sensing import CameraPose, camera_basis
from skyvln_eval.sim.sensors import Capture
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
    pose = CameraPose(0.0, 0.0, 50.0, 0.0, 30.0)
    captures = [
        [
            ("front", Capture(0.0, 30.0, seen, pose)),
            ("again", Capture(0.0, 30.0, seen.copy(), pose)),
        ],
        [
            ("front", Capture(0.0, 30.0, seen.copy(), pose)),
            ("down", Capture(0.0, 90.0, other, pose)),
        ],
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


def rotate(q: dict[str, float], v: np.ndarray) -> np.ndarray:
    """``v`` rotated by the unit quaternion ``q`` (Foxglove's x, y, z, w)."""
    axis, w = np.array([q["x"], q["y"], q["z"]]), q["w"]
    return v + 2.0 * np.cross(axis, np.cross(axis, v) + w * v)


@pytest.mark.parametrize("yaw_rad", [0.0, 0.7, np.pi / 2, 2.5, np.pi, -2.0, -np.pi / 2])
@pytest.mark.parametrize("pitch_deg", [0.0, 10.0, 45.0, 89.0, 90.0])
def test_a_captured_views_frame_looks_where_its_camera_looked(
    yaw_rad: float, pitch_deg: float
) -> None:
    # The frame an image names (camera/<view>) is in /tf: at the camera, its optical axes
    # (x right, y down in the image, z along the view) those the renderer cast rays along.
    pose = CameraPose(12.0, -3.0, 80.0, yaw_rad, pitch_deg)
    tf = camera_view_tf(7, "camera/front", pose)
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == (t.MAP_FRAME, "camera/front")
    assert [tf["translation"][k] for k in "xyz"] == [12.0, -3.0, 80.0]
    q = tf["rotation"]
    assert np.isclose(sum(q[k] ** 2 for k in "xyzw"), 1.0)
    forward, right, up = camera_basis(pose)
    for optical, expected in zip(np.eye(3), (right, -up, forward), strict=True):
        np.testing.assert_allclose(rotate(q, optical), expected, atol=1e-12)
