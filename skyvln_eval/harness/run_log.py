"""Run MCAPs: one log per (run, episode), Foxglove-ready, with everything the run did.

A run log holds the episode itself (its metadata, so :func:`read_episode` works on it,
saying what this log holds: observations or not, the map tile's size, 0 for none, and
``clock_step_ns`` in official mode only; GT path, GT views, destination, attention and map
tile at time 0; the dialog at time 0, since the agent is given it at the start) and then,
on the run's clock (simulated seconds; one second per step in official mode):

- ``/tf`` and ``/run/path``: where the drone was (and, at each decision, each captured
  view's ``camera/<view name>`` optical frame), ``/run/views``: every visited view;
- ``/camera/observation``: the view below the drone at each decision (224 x 224, JPEG);
- ``/camera/views``: the camera images the agent captured for each decision (JPEG), each
  with ``frame_id`` ``camera/<view name>`` (the names its trace gives the views, which its
  sightings refer to);
- ``/agent/step`` (:data:`AGENT_STEP`): thought, action, feedback and the decision's
  trace (sub-goals, detections with HSD sectors, HSD matches, the TrackBack memory graph),
  ``/agent/log``: the same as text, ``/agent/target``: each action's target pose;
- ``/llm/exchange``: every request to the LLM: prompt (and which images went with it),
  response, decoding settings, and each attempt with its outcome, tokens, cost, latency,
  finish reason and error;
- dynamics mode: ``/control/step`` per control step (state, reference, command, solve
  statistics, clearance) and ``/sim/obstacles`` (the spheres, every half second).

Messages are collected with their times and written in time order (static content
first); the writer renames the file into place only when it is complete.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from skyvln_eval.agent.actions import Action, action_record
from skyvln_eval.avdn.geometry import view_centre
from skyvln_eval.avdn.imagery import observe_view
from skyvln_eval.avdn.records import Episode
from skyvln_eval.converters import messages as fx
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.convert import (
    DEFAULT_OPTIONS,
    ConvertOptions,
    encode_image,
    episode_metadata,
    write_dialog_turn,
    write_static_content,
)
from skyvln_eval.converters.float_text import float_texts
from skyvln_eval.converters.json_template import JsonTemplate, slot
from skyvln_eval.converters.writer import McapLogWriter
from skyvln_eval.frames import ViewPose, latlng_to_enu, view_to_pose
from skyvln_eval.harness.control_messages import control_messages, drone_tf, ns
from skyvln_eval.harness.crashpoints import crash_point
from skyvln_eval.sensing import CameraPose, camera_basis
from skyvln_eval.sim.obstacles import ObstacleScenario
from skyvln_eval.sim.sensors import Capture
from skyvln_eval.worlds.tile import WorldTile

VISITED_RGBA = (0.1, 0.6, 1.0, 1.0)
OBSTACLE_RGBA = (1.0, 0.3, 0.1, 0.6)
OBSTACLE_SAMPLE_S = 0.5


@dataclass
class Step:
    """One decision of the agent as the run log needs it."""

    t_s: float
    step_index: int
    view: NDArray[np.float64]
    thought: str
    action: Action
    feedback: str | None
    trace: Mapping[str, Any]
    target: ViewPose | None = None
    camera_views: Sequence[tuple[str, Capture]] = ()


def named_views(trace: Mapping[str, Any], captures: Sequence[Capture]) -> list[tuple[str, Capture]]:
    """The decision's captures, named as the agent's trace names its views (by heading and
    pitch), else ``heading <h> pitch <p>``."""
    names = {
        (round(float(v["heading_deg"]), 1), round(float(v["pitch_deg"]), 1)): str(v["name"])
        for v in trace.get("views") or []
        if isinstance(v, Mapping) and {"name", "heading_deg", "pitch_deg"} <= v.keys()
    }
    named = []
    for capture in captures:
        key = (round(capture.heading_deg, 1), round(capture.pitch_deg, 1))
        named.append((names.get(key, f"heading {key[0]:g} pitch {key[1]:g}"), capture))
    return named


@dataclass
class RunLogContent:
    """Everything a run log shows, from either execution mode."""

    steps: list[Step]
    views: list[NDArray[np.float64]]
    view_times_s: list[float]
    control_log: pd.DataFrame | None = None
    obstacle_segments: list[tuple[float, float, ObstacleScenario]] = field(default_factory=list)
    #: The fixed time between decisions (official mode: one second), or None when each
    #: comes at its own simulated time (dynamics mode).
    clock_step_ns: int | None = None
    #: The run's and the episode's outcome (system, config, seed, status, ...), known
    #: once the episode is judged.
    run_metadata: dict[str, str] = field(default_factory=dict)


class _Messages:
    """Messages collected with (time, order) and written sorted by both."""

    def __init__(self) -> None:
        self.items: list[tuple[int, int, str, str, Any]] = []

    def add(self, t_ns: int, topic: str, message: Any) -> None:
        self.items.append((t_ns, len(self.items), topic, t.TOPICS[topic], message))

    def write(self, writer: McapLogWriter) -> None:
        for t_ns, _, topic, schema, message in sorted(self.items, key=lambda m: (m[0], m[1])):
            writer.write(topic, schema, message, t_ns)


def _view_loop(view: NDArray[np.float64], episode: Episode) -> list[list[float]]:
    xy = latlng_to_enu(view, episode.georef)
    return [[float(x), float(y), 0.0] for x, y in xy]


def _trace_without_exchanges(trace: Mapping[str, Any]) -> dict[str, Any]:
    """The trace as JSON values (what is not JSON as its ``str``), without the exchanges
    (they have a topic of their own)."""
    return json.loads(json.dumps({k: v for k, v in trace.items() if k != "exchanges"}, default=str))


def _agent_step_fields(
    t_ns: int, episode_id: str, step: Step, record: Mapping[str, Any]
) -> dict[str, Any]:
    return {
        "timestamp": fx.timestamp(t_ns),
        "episode_id": episode_id,
        "step_index": step.step_index,
        "thought": step.thought,
        "action": record,
        "feedback": step.feedback,
    }


def agent_step_message(
    t_ns: int, episode_id: str, step: Step, record: Mapping[str, Any]
) -> dict[str, Any]:
    """The ``/agent/step`` message (the reference for :func:`agent_step_json`)."""
    fields = _agent_step_fields(t_ns, episode_id, step, record)
    return fields | {"trace": _trace_without_exchanges(step.trace)}


def agent_step_json(
    t_ns: int, episode_id: str, step: Step, record: Mapping[str, Any]
) -> bytes | dict[str, Any]:
    """:func:`agent_step_message` as the writer encodes it, with the trace encoded once,
    not encoded, decoded and encoded again: encoding it with what is not JSON as its
    ``str`` writes the text the round trip gave, filled in the message's template. A
    message the writer would refuse (a NaN) stays the dict, so the writer fails on it as
    before."""
    trace = {k: v for k, v in step.trace.items() if k != "exchanges"}
    fields = _agent_step_fields(t_ns, episode_id, step, record)
    try:  # (a string that is not UTF-8, a lone surrogate, is a ValueError too)
        text = json.dumps(
            trace, separators=(",", ":"), ensure_ascii=False, allow_nan=False, default=str
        )
        template = JsonTemplate(fields | {"trace": slot(0)})
        # The fields hold the model's words: a thought that spells a slot marker would
        # be taken for one, so only the template with the trace's slot alone is used.
        if template.slots != 1:
            raise ValueError("a field holds a slot marker")
        return template.fill(text)
    except (TypeError, ValueError):
        return agent_step_message(t_ns, episode_id, step, record)


class _ImageEncoder:
    """Each distinct image encoded once per log: the agent often captures the same pixels
    again (a cancelled step looks again from where it was), and the encoding, a pure
    function of the pixels, is the same bytes each time."""

    def __init__(self, options: ConvertOptions) -> None:
        self._options = options
        self._by_pixels: dict[tuple[bool, tuple[int, ...], str, bytes], bytes] = {}

    def encode(self, image: NDArray[np.uint8], rgb: bool) -> bytes:
        """``image`` (BGR, or RGB if ``rgb``) encoded. The key is the image as given: the
        camera's RGB arrays are contiguous, so keying them costs a copy, not a flip."""
        key = (rgb, image.shape, image.dtype.str, image.tobytes())
        if key not in self._by_pixels:
            # A channel swap into new memory: OpenCV would copy a reversed-channel view
            # element by element (twice the JPEG encoding's own time), to the same pixels.
            bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image
            options = self._options
            self._by_pixels[key] = encode_image(bgr, options.image_format, options.jpeg_quality)
        return self._by_pixels[key]


def _agent_messages(
    out: _Messages,
    episode: Episode,
    world: WorldTile | None,
    steps: Sequence[Step],
    options: ConvertOptions,
    observations: bool,
    flown_at: frozenset[int] = frozenset(),
) -> None:
    """The messages of each decision's view; ``flown_at``: the times (ns) a control step
    placed the drone, where the view's ``/tf`` would repeat it (a hair apart)."""
    encoded: dict[bytes, bytes] = {}  # a view seen again (a cancelled step) is not re-rendered
    images = _ImageEncoder(options)
    for step in steps:
        t_ns = ns(step.t_s)
        _place_drone(out, episode, step.view, t_ns, t_ns not in flown_at)
        if world is not None and observations:
            key = np.asarray(step.view, dtype=np.float64).tobytes()
            if key not in encoded:
                encoded[key] = images.encode(
                    observe_view(world.bgr, step.view, episode.georef), rgb=False
                )
            image = encoded[key]
            out.add(
                t_ns,
                t.TOPIC_OBSERVATION,
                fx.compressed_image_json(t_ns, t.CAMERA_FRAME, image, options.image_format),
            )
        for name, capture in step.camera_views:
            frame = f"{t.CAMERA_VIEW_FRAME_PREFIX}{name}"
            # Where the camera was and how it looked, so the 3-D panel places the frame
            # the image names (with or without the images: the trace's views name it too).
            out.add(t_ns, t.TOPIC_TF, camera_view_tf(t_ns, frame, capture.pose))
            if observations:
                jpeg = images.encode(capture.rgb, rgb=True)
                out.add(
                    t_ns,
                    t.TOPIC_CAMERA_VIEWS,
                    fx.compressed_image_json(t_ns, frame, jpeg, options.image_format),
                )
        record = action_record(step.action)
        out.add(t_ns, t.TOPIC_AGENT_STEP, agent_step_json(t_ns, episode.episode_id, step, record))
        out.add(
            t_ns,
            t.TOPIC_AGENT_LOG,
            fx.log(t_ns, "agent", f"step {step.step_index}: {json.dumps(record)} | {step.thought}"),
        )
        for exchange in step.trace.get("exchanges", []) or []:
            out.add(
                t_ns,
                t.TOPIC_LLM_EXCHANGE,
                {
                    "timestamp": fx.timestamp(t_ns),
                    "episode_id": episode.episode_id,
                    "step_index": step.step_index,
                    **exchange,
                },
            )
        if step.target is not None:
            target = fx.pose(step.target.x_m, step.target.y_m, step.target.z_m, step.target.yaw_rad)
            out.add(t_ns, t.TOPIC_AGENT_TARGET, fx.pose_in_frame(t_ns, t.MAP_FRAME, target))


def camera_view_tf(t_ns: int, frame: str, pose: CameraPose) -> Any:
    """The optical frame of a captured view in the map: at the camera, looking as it did."""
    translation = fx.vector3(pose.x_m, pose.y_m, pose.z_m)
    forward, right, up = camera_basis(pose)
    rotation = fx.optical_frame_quaternion(forward.tolist(), right.tolist(), up.tolist())
    return fx.frame_transform(t_ns, t.MAP_FRAME, frame, translation, rotation)


def _place_drone(
    out: _Messages, episode: Episode, view: Any, t_ns: int, transform: bool = True
) -> None:
    """The drone at ``view`` at ``t_ns``: its ``/tf`` (unless a control step placed it
    then) and where it is on the globe, as an episode log says it (Foxglove's Map panel
    reads ``/drone/gps``, so one layout shows both kinds of log)."""
    pose = view_to_pose(view, episode.georef)
    if transform:
        out.add(t_ns, t.TOPIC_TF, drone_tf(t_ns, pose))
    lat, lng = view_centre(np.asarray(view, dtype=np.float64)[None])[0]
    out.add(t_ns, t.TOPIC_GPS, fx.location_fix(t_ns, t.DRONE_FRAME, lat, lng, pose.z_m))


def _path_messages(
    out: _Messages, episode: Episode, content: RunLogContent, placed: frozenset[int]
) -> None:
    """The path and view squares at each view; the drone placed at a view no decision or
    control step placed it at (``placed``): where it ended, after its last move."""
    poses: list[Any] = []
    for k, (view, t_s) in enumerate(zip(content.views, content.view_times_s, strict=True)):
        t_ns = ns(t_s)
        if t_ns not in placed:
            _place_drone(out, episode, view, t_ns)
        pose = view_to_pose(view, episode.georef)
        poses.append(fx.pose(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad))
        out.add(t_ns, t.TOPIC_RUN_PATH, fx.poses_in_frame(t_ns, t.MAP_FRAME, list(poses)))
        square = fx.line(_view_loop(view, episode), VISITED_RGBA, True, 2.0)
        out.add(
            t_ns,
            t.TOPIC_RUN_VIEWS,
            fx.scene_update(
                t_ns, t.MAP_FRAME, f"visited_view_{k}", [square], {"episode_id": episode.episode_id}
            ),
        )


def _control_messages(out: _Messages, log: pd.DataFrame) -> None:
    for t_ns, topic, message in control_messages(log):
        out.add(t_ns, topic, message)


def obstacle_message(t_ns: int, scenario: ObstacleScenario, centres: Sequence[Any]) -> Any:
    """The ``/sim/obstacles`` message at ``t_ns``: a sphere per obstacle at its centre."""
    spheres = [
        fx.sphere(list(centre), 2.0 * ob.radius_m, OBSTACLE_RGBA)
        for centre, ob in zip(centres, scenario.obstacles, strict=True)
    ]
    return fx.scene_update(t_ns, t.MAP_FRAME, "obstacles", [], {"scenario": scenario.name}, spheres)


def _obstacle_template(scenario: ObstacleScenario) -> JsonTemplate:
    """:func:`obstacle_message` with slots: the time's seconds and nanoseconds, then each
    centre's x, y and z."""
    message = obstacle_message(0, scenario, [(0.0, 0.0, 0.0)] * len(scenario.obstacles))
    entity = message["entities"][0]
    entity["timestamp"] = fx.timestamp_slots()
    for k, sphere in enumerate(entity["spheres"]):
        first = 2 + 3 * k
        sphere["pose"]["position"] = {"x": slot(first), "y": slot(first + 1), "z": slot(first + 2)}
    return JsonTemplate(message)


def _obstacle_messages(
    out: _Messages, segments: Sequence[tuple[float, float, ObstacleScenario]]
) -> None:
    for start_s, end_s, scenario in segments:
        if not scenario.obstacles:
            continue
        times = np.arange(start_s, end_s + 1e-9, OBSTACLE_SAMPLE_S)
        # (times, obstacles, 3): every centre at every time.
        centres = np.stack([ob.motion.position_m(times) for ob in scenario.obstacles], axis=1)
        times_ns = [ns(float(t_s)) for t_s in times]
        if not np.isfinite(centres).all():  # the writer refuses them, as the dicts
            for t_ns, at in zip(times_ns, centres.tolist(), strict=True):
                out.add(t_ns, t.TOPIC_OBSTACLES, obstacle_message(t_ns, scenario, at))
            continue
        template = _obstacle_template(scenario)
        texts = float_texts(centres.ravel())
        per_time = centres.shape[1] * 3
        for i, t_ns in enumerate(times_ns):
            row = texts[i * per_time : (i + 1) * per_time]
            out.add(t_ns, t.TOPIC_OBSTACLES, template.fill(*fx.timestamp_texts(t_ns), *row))


def write_run_log(
    path: str | Path,
    episode: Episode,
    world: WorldTile | None,
    content: RunLogContent,
    observations: bool = True,
    options: ConvertOptions = DEFAULT_OPTIONS,
) -> None:
    """Write one run log (see the module docstring) to ``path``, atomically.

    A write that fails (a full disk) raises an ``OSError`` that names ``path``: the
    writer's own errors do not say which file they were writing.
    """
    try:
        _write_run_log(path, episode, world, content, observations, options)
    except OSError as error:
        if error.filename is not None:
            raise
        raise OSError(error.errno, error.strerror, str(path)) from error


#: Topics whose messages are images of what the drone saw.
_OBSERVATION_TOPICS = frozenset({t.TOPIC_OBSERVATION, t.TOPIC_CAMERA_VIEWS})


def _written_options(
    options: ConvertOptions, world: WorldTile | None, observations: bool, out: _Messages
) -> ConvertOptions:
    """The options as the log holds them: a map tile only from a world, when images are
    logged; observations if any image of what the drone saw is in it."""
    tile = world is not None and observations and options.map_tile_max_side_px > 0
    return replace(
        options,
        observations=any(item[2] in _OBSERVATION_TOPICS for item in out.items),
        map_tile_max_side_px=options.map_tile_max_side_px if tile else 0,
    )


def _write_run_log(
    path: str | Path,
    episode: Episode,
    world: WorldTile | None,
    content: RunLogContent,
    observations: bool,
    options: ConvertOptions,
) -> None:
    out = _Messages()
    log = content.control_log
    flown_at = frozenset(ns(s) for s in log["t_s"].tolist()) if log is not None else frozenset()
    _agent_messages(out, episode, world, content.steps, options, observations, flown_at)
    # The control steps before the path at one time: a reader that draws the path flown
    # so far when the path message comes has the drone's pose of that time by then (an
    # audit: the viewer's flown path ended a control step short of the drone).
    if log is not None and len(log):
        _control_messages(out, log)
    _path_messages(out, episode, content, flown_at | {ns(step.t_s) for step in content.steps})
    _obstacle_messages(out, content.obstacle_segments)
    # Said as written, not as asked: the converter's defaults (observations, a 384 px
    # tile, one view a second) were claimed for logs without images and for dynamics runs.
    written = _written_options(options, world, observations, out)
    with McapLogWriter(path) as writer:
        writer.add_metadata(
            t.EPISODE_METADATA, episode_metadata(episode, written, content.clock_step_ns)
        )
        writer.add_metadata(
            t.RUN_METADATA,
            {
                "format": t.RUN_FORMAT,
                "version": str(t.RUN_FORMAT_VERSION),
                **content.run_metadata,
            },
        )
        poses = [view_to_pose(corners, episode.georef) for corners in episode.gt_path_corners]
        write_static_content(episode, world if observations else None, poses, writer, written)
        crash_point("run-log-start")  # test hook: no-op unless $SKYVLN_EVAL_CRASH_AT says
        for index, turn in enumerate(episode.dialog()):
            write_dialog_turn(writer, episode.episode_id, turn, index, 0)
        out.write(writer)
        crash_point("run-log-end")
    crash_point("run-log-written")  # renamed into place: a worker that dies after it
