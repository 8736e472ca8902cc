"""Schemas: official Foxglove names and content, own schemas versioned, every message valid."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import jsonschema
import pytest

from skyvln_eval.avdn import Episode, parse_record
from skyvln_eval.converters import McapLogWriter, read_log, read_log_bytes
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.validate import (
    check_log,
    check_log_bytes,
    check_paths,
)
from skyvln_eval.frames import latlng_to_enu, view_to_pose
from tests.conftest import REPO, make_record
from tests.converters.conftest import ConvertedSample, convert_to_bytes, synthetic_world

SCHEMA_DIR = REPO / "skyvln_eval" / "converters" / "schemas"


def test_every_declared_topic_has_a_declared_schema() -> None:
    assert set(t.TOPICS.values()) <= set(t.SCHEMAS)
    for name, spec in t.SCHEMAS.items():
        schema = t.schema_json(name)
        assert schema["title"] == name, "the MCAP schema name is the schema's own title"
        jsonschema.Draft202012Validator.check_schema(schema)
        assert json.loads(t.schema_bytes(name)) == schema
        assert spec.is_own == name.startswith("skyvln_eval."), name
        assert name.startswith(("foxglove.", "skyvln_eval."))


def test_vendored_foxglove_schemas_carry_origin_and_licence() -> None:
    folder = SCHEMA_DIR / "foxglove"
    source = (folder / "SOURCE.md").read_text()
    assert "@foxglove/schemas" in source and t.FOXGLOVE_SCHEMAS_VERSION in source
    assert "MIT License" in (folder / "LICENSE").read_text()
    vendored = {p.name.removesuffix(".json") for p in folder.glob("foxglove.*.json")}
    used = {name for name in t.SCHEMAS if name.startswith("foxglove.")}
    assert vendored == used


def test_every_message_of_every_sample_log_validates_against_its_channel_schema(
    converted_sample: ConvertedSample,
) -> None:
    checks, folder_issues = check_paths([converted_sample.out_dir])
    assert folder_issues == []
    assert len(checks) == sum(len(e) for e in converted_sample.episodes.values())
    assert sum(c.messages for c in checks) > 1000
    problems = [str(i) for c in checks for i in c.issues]
    assert problems == []


def test_messages_are_checked_against_the_schema_stored_in_their_channel() -> None:
    """A message that breaks its channel's schema is reported with topic, sequence and field."""
    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        writer.write(
            t.TOPIC_DIALOG_LOG,
            t.LOG,
            {
                "timestamp": {"sec": 0, "nsec": 0},
                "level": 9,
                "message": "m",
                "name": "n",
                "file": "",
                "line": 0,
            },
            0,
        )
        writer.write(
            t.TOPIC_GT_OBSERVATION,
            t.COMPRESSED_IMAGE,
            {
                "timestamp": {"sec": 1, "nsec": 0},
                "frame_id": "camera",
                "data": "not base64!",
                "format": "jpeg",
            },
            1_000_000_000,
        )
        writer.write(
            t.TOPIC_START_POSE,
            t.POSE_IN_FRAME,
            {"timestamp": {"sec": 5, "nsec": 0}, "frame_id": "map", "pose": {"position": {}}},
            2_000_000_000,
        )
    check = check_log_bytes(buffer.getvalue(), "bad.mcap")
    assert check.messages == 3
    text = "\n".join(str(i) for i in check.issues)
    assert "/dialog/log message 0 /level" in text
    assert "/camera/gt_observation message 1 /data" in text and "base64" in text
    assert "/episode/start_pose message 2 /pose/position" in text
    assert "timestamp" in text and "log time is 2000000000" in text


def test_a_channel_schema_other_than_the_toolkits_is_reported_and_not_trusted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # An audit wrote a log whose foxglove.CompressedImage schema lacked the base64
    # contentEncoding (Foxglove could not decode the images): validate said nothing, its
    # messages being checked against that very schema.
    stub = json.dumps({"type": "object"}).encode()
    real = t.schema_bytes
    buffer = io.BytesIO()
    with monkeypatch.context() as patched:
        patched.setattr(
            t, "schema_bytes", lambda name: stub if name == t.COMPRESSED_IMAGE else real(name)
        )
        with McapLogWriter(buffer) as writer:
            image = {"timestamp": {"sec": 0, "nsec": 0}, "frame_id": "camera", "format": "jpeg"}
            writer.write(t.TOPIC_GT_OBSERVATION, t.COMPRESSED_IMAGE, image, 0)  # no data
    check = check_log_bytes(buffer.getvalue(), "tampered.mcap")
    text = "\n".join(str(i) for i in check.issues)
    assert "schema foxglove.CompressedImage differs from the toolkit's copy" in text
    assert "'data' is a required property" in text  # checked against the real schema


def test_own_schema_version_is_in_the_channel_metadata() -> None:
    episode = Episode("val_seen", "andh", (parse_record(make_record()),))
    log = read_log_bytes(convert_to_bytes(episode, synthetic_world()))
    dialog = next(c for c in log.channels if c.topic == t.TOPIC_DIALOG)
    assert dialog.metadata == {t.SCHEMA_VERSION_KEY: str(t.SCHEMAS[t.DIALOG_TURN].version)}
    assert all(not c.metadata for c in log.channels if c.topic != t.TOPIC_DIALOG)


@pytest.mark.parametrize("topic", [t.TOPIC_GT_VIEWS, t.TOPIC_GT_PATH, t.TOPIC_GPS])
def test_geometry_is_in_the_map_frame_in_enu_metres(
    converted_sample: ConvertedSample, topic: str
) -> None:
    episode = converted_sample.episodes[("val_unseen", "andh")][0]
    log = read_log(
        converted_sample.reports[("val_unseen", "andh")].out_dir / f"{episode.episode_id}.mcap"
    )
    messages = [m.decode() for m in log.topic(topic)]
    views = episode.gt_path_corners
    if topic == t.TOPIC_GT_VIEWS:
        lines = messages[0]["entities"][0]["lines"]
        assert messages[0]["entities"][0]["frame_id"] == t.MAP_FRAME
        expected = latlng_to_enu(views, episode.georef)
        got = [[[p["x"], p["y"]] for p in line["points"]] for line in lines]
        assert got == expected.tolist()
    elif topic == t.TOPIC_GT_PATH:
        poses = messages[0]["poses"]
        for view, pose in zip(views, poses, strict=True):
            p = view_to_pose(view, episode.georef)
            assert [pose["position"][k] for k in "xyz"] == [p.x_m, p.y_m, p.z_m]
            assert pose["orientation"]["z"] == pytest.approx(math.sin(p.yaw_rad / 2))
    else:
        centres = views.mean(axis=1)
        assert [[m["latitude"], m["longitude"]] for m in messages] == centres.tolist()


def test_check_log_reports_an_unreadable_file_once(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"nope")
    check = check_log(path)
    assert len(check.issues) == 1 and "not an MCAP file" in check.issues[0].message


def test_importing_the_converters_imports_no_heavy_dependency() -> None:
    import subprocess
    import sys

    code = (
        "import sys, skyvln_eval.converters\n"
        "heavy = ('datasets', 'torch', 'transformers', 'ray', 'openai')\n"
        "print([m for m in heavy if m in sys.modules])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]"
