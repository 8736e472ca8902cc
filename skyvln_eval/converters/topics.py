"""Every MCAP topic, schema, frame and metadata name the toolkit writes, in one place.

Episode logs (converted from AVDN) and run logs (written by the replay harness) use the
same writer and these names, so Foxglove layouts and notebooks work on both. A topic is
declared once with its schema; the writer refuses an undeclared topic or a topic written
with another schema, so a typo cannot create a new channel silently.

Schemas are JSON schemas (MCAP ``jsonschema`` encoding, messages ``json``). Foxglove
well-known schemas keep their exact names and official content (vendored under
``schemas/foxglove``, see its SOURCE.md); the toolkit's own schemas are named
``skyvln_eval.<Type>`` and carry a version, stored in the channel metadata and checked on
read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any, Final

#: Version of the episode log layout (topics, metadata keys, clock). Checked on read.
EPISODE_FORMAT: Final = "skyvln_eval.episode_log"
EPISODE_FORMAT_VERSION: Final = 1

#: Version of the run log layout (episode content plus the run's topics). Checked on read.
RUN_FORMAT: Final = "skyvln_eval.run_log"
RUN_FORMAT_VERSION: Final = 1

#: MCAP header strings: fixed, so identical inputs give byte-identical files.
MCAP_PROFILE: Final = ""
MCAP_LIBRARY: Final = "skyvln-eval"

#: The npm package the vendored Foxglove schemas come from.
FOXGLOVE_SCHEMAS_PACKAGE: Final = "@foxglove/schemas"
FOXGLOVE_SCHEMAS_VERSION: Final = "2.1.0"

MESSAGE_ENCODING: Final = "json"
SCHEMA_ENCODING: Final = "jsonschema"
#: Channel metadata key holding an own schema's version.
SCHEMA_VERSION_KEY: Final = "schema_version"

# Metadata record names and keys.
EPISODE_METADATA: Final = "skyvln_eval.episode"
CONVERSION_METADATA: Final = "skyvln_eval.conversion"
RUN_METADATA: Final = "skyvln_eval.run"

# Frames. ``map`` is the ENU frame of skyvln_eval.frames (x east, y north, metres from the
# map's south-west corner); ``drone`` is the drone's level heading frame (x forward, y left,
# z up: its position and yaw, no roll or pitch), on which the gimballed downward camera
# hangs; ``camera`` is that camera's optical frame (x right, y down in the image, z into
# the scene); ``body`` (flown runs only) is the airframe: the drone's position with its
# full attitude (the model's world-frame roll and pitch after its yaw), a child of ``map``.
MAP_FRAME: Final = "map"
DRONE_FRAME: Final = "drone"
CAMERA_FRAME: Final = "camera"
BODY_FRAME: Final = "body"
MAP_TILE_FRAME: Final = "map_tile"

# Schema names.
COMPRESSED_IMAGE: Final = "foxglove.CompressedImage"
FRAME_TRANSFORM: Final = "foxglove.FrameTransform"
LOCATION_FIX: Final = "foxglove.LocationFix"
LOG: Final = "foxglove.Log"
POSE_IN_FRAME: Final = "foxglove.PoseInFrame"
POSES_IN_FRAME: Final = "foxglove.PosesInFrame"
SCENE_UPDATE: Final = "foxglove.SceneUpdate"
DIALOG_TURN: Final = "skyvln_eval.DialogTurn"
AGENT_STEP: Final = "skyvln_eval.AgentStep"
LLM_EXCHANGE: Final = "skyvln_eval.LLMExchange"
CONTROL_STEP: Final = "skyvln_eval.ControlStep"

# Episode topics: static content (log time 0) ...
TOPIC_MAP_TILE: Final = "/map/tile"
TOPIC_GT_PATH: Final = "/episode/gt_path"
TOPIC_GT_VIEWS: Final = "/episode/gt_views"
TOPIC_DESTINATION: Final = "/episode/destination"
TOPIC_ATTENTION: Final = "/episode/attention"
TOPIC_START_POSE: Final = "/episode/start_pose"
# ... and time series on the episode clock.
TOPIC_TF: Final = "/tf"
TOPIC_GPS: Final = "/drone/gps"
TOPIC_GT_OBSERVATION: Final = "/camera/gt_observation"
TOPIC_DIALOG: Final = "/dialog/turns"
TOPIC_DIALOG_LOG: Final = "/dialog/log"
# Run logs (replay harness): the episode's static content and dialog, then on the run's
# simulated clock ...
TOPIC_RUN_VIEWS: Final = "/run/views"  # visited view squares, one entity per view
TOPIC_RUN_PATH: Final = "/run/path"  # the flown (or stepped) path so far
TOPIC_OBSERVATION: Final = "/camera/observation"  # what the agent saw below it at each decision
TOPIC_CAMERA_VIEWS: Final = "/camera/views"  # the camera images the agent captured
#: ``frame_id`` of a ``/camera/views`` image: this prefix and the agent's name of the view.
CAMERA_VIEW_FRAME_PREFIX: Final = "camera/"
TOPIC_AGENT_STEP: Final = "/agent/step"
TOPIC_AGENT_LOG: Final = "/agent/log"  # thought and action as text, for the Log panel
TOPIC_AGENT_TARGET: Final = "/agent/target"  # target pose of each action (dynamics mode)
TOPIC_LLM_EXCHANGE: Final = "/llm/exchange"
TOPIC_CONTROL_STEP: Final = "/control/step"
TOPIC_OBSTACLES: Final = "/sim/obstacles"  # obstacle spheres, sampled along the flight


@dataclass(frozen=True)
class SchemaSpec:
    """A JSON schema the toolkit writes: its MCAP name, vendored file and own version.

    ``version`` is ``None`` for Foxglove schemas (their version is the vendored package's).
    """

    name: str
    resource: str
    version: int | None = None

    @property
    def is_own(self) -> bool:
        return self.version is not None


SCHEMAS: Final[dict[str, SchemaSpec]] = {
    spec.name: spec
    for spec in (
        SchemaSpec(COMPRESSED_IMAGE, "foxglove/foxglove.CompressedImage.json"),
        SchemaSpec(FRAME_TRANSFORM, "foxglove/foxglove.FrameTransform.json"),
        SchemaSpec(LOCATION_FIX, "foxglove/foxglove.LocationFix.json"),
        SchemaSpec(LOG, "foxglove/foxglove.Log.json"),
        SchemaSpec(POSE_IN_FRAME, "foxglove/foxglove.PoseInFrame.json"),
        SchemaSpec(POSES_IN_FRAME, "foxglove/foxglove.PosesInFrame.json"),
        SchemaSpec(SCENE_UPDATE, "foxglove/foxglove.SceneUpdate.json"),
        SchemaSpec(DIALOG_TURN, "skyvln_eval/skyvln_eval.DialogTurn.json", version=1),
        SchemaSpec(AGENT_STEP, "skyvln_eval/skyvln_eval.AgentStep.json", version=1),
        SchemaSpec(LLM_EXCHANGE, "skyvln_eval/skyvln_eval.LLMExchange.json", version=5),
        SchemaSpec(CONTROL_STEP, "skyvln_eval/skyvln_eval.ControlStep.json", version=2),
    )
}

#: Every topic and the one schema its messages use.
TOPICS: Final[dict[str, str]] = {
    TOPIC_MAP_TILE: COMPRESSED_IMAGE,
    TOPIC_GT_PATH: POSES_IN_FRAME,
    TOPIC_GT_VIEWS: SCENE_UPDATE,
    TOPIC_DESTINATION: SCENE_UPDATE,
    TOPIC_ATTENTION: SCENE_UPDATE,
    TOPIC_START_POSE: POSE_IN_FRAME,
    TOPIC_TF: FRAME_TRANSFORM,
    TOPIC_GPS: LOCATION_FIX,
    TOPIC_GT_OBSERVATION: COMPRESSED_IMAGE,
    TOPIC_DIALOG: DIALOG_TURN,
    TOPIC_DIALOG_LOG: LOG,
    TOPIC_RUN_VIEWS: SCENE_UPDATE,
    TOPIC_RUN_PATH: POSES_IN_FRAME,
    TOPIC_OBSERVATION: COMPRESSED_IMAGE,
    TOPIC_CAMERA_VIEWS: COMPRESSED_IMAGE,
    TOPIC_AGENT_STEP: AGENT_STEP,
    TOPIC_AGENT_LOG: LOG,
    TOPIC_AGENT_TARGET: POSE_IN_FRAME,
    TOPIC_LLM_EXCHANGE: LLM_EXCHANGE,
    TOPIC_CONTROL_STEP: CONTROL_STEP,
    TOPIC_OBSTACLES: SCENE_UPDATE,
}


@cache
def schema_json(name: str) -> dict[str, Any]:
    """The JSON schema of a declared schema name, as a dict (cached; do not mutate)."""
    spec = SCHEMAS[name]
    text = resources.files("skyvln_eval.converters").joinpath("schemas", *spec.resource.split("/"))
    loaded: dict[str, Any] = json.loads(text.read_text(encoding="utf-8"))
    return loaded


@cache
def schema_bytes(name: str) -> bytes:
    """The schema as stored in MCAP schema records: compact JSON, UTF-8 (same content)."""
    return json.dumps(schema_json(name), separators=(",", ":"), ensure_ascii=False).encode()
