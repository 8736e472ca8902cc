"""Build the Rerun recording of one episode from its run MCAP, streaming.

:func:`write_recording` opens the log (:class:`~.logs.RunLogStream`), logs the static
content (map tile, ground truth, goal) as timeless data, then every message in log-time
order on the ``decision`` and ``sim_time`` timelines, and writes an ``.rrd`` file under a
temporary name renamed into place when complete. The log is the only source: nothing is
recomputed from the dataset or the harness. Entity paths are in :mod:`.entities`.
"""

from __future__ import annotations

import bisect
import os
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import yaml

from skyvln_eval.converters import topics as t
from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer import scene, text
from skyvln_eval.viewer.blueprint import episode_blueprint
from skyvln_eval.viewer.deps import rerun_sdk
from skyvln_eval.viewer.logs import EpisodeLogRef, RunLogStream
from skyvln_eval.viewer.signals import ControlSignals

Json = Mapping[str, Any]
#: Topics whose first decision marks the decision clock: agent steps (run logs), else GT
#: views (episode logs, one GPS fix per view).
_CLOCK_TOPICS = (t.TOPIC_AGENT_STEP, t.TOPIC_GPS)
_DEFAULT_IMAGE_PX = 224


@dataclass(frozen=True)
class RecordingSummary:
    """What one recording holds: where it was written and the rows logged per entity."""

    path: Path
    episode: EpisodeLogRef
    recording_id: str
    decisions: int
    rows: dict[str, int]


def recording_id(ref: EpisodeLogRef, run: Mapping[str, str]) -> str:
    """Unique per (run configuration, split, episode), so several runs can be opened together."""
    digest = run.get("config_digest", "episode-log")
    return f"{ref.split}/{ref.episode_id}@{digest}"


def _image_px(run: Mapping[str, str]) -> tuple[int, int]:
    """The agent's camera image size (for HSD sector boxes), from the run's resolved config."""
    try:
        config = yaml.safe_load(run.get("config", "")) or {}
        size = int(config["agent"]["perception"]["image_px"])
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        size = _DEFAULT_IMAGE_PX
    return size, size


class _Recorder:
    """Logs one episode's messages into an open recording stream (one handler per topic)."""

    def __init__(self, rr: ModuleType, rec: Any, log: RunLogStream) -> None:
        self.rr, self.rec, self.log = rr, rec, log
        episode = log.episode()
        self.episode = episode
        self.frame = e.MapFrame(episode.georef)
        self.rows: Counter[str] = Counter()
        self.flight = scene.Flight()
        self.signals = ControlSignals()
        self.decision_times = self._decision_times()
        self.image_px = _image_px(log.run_metadata)
        self.dialog: list[Json] = []
        self.modules: list[str] = []
        self.detection_views: list[str] = []
        self.last_view: tuple[scene.Strip, int] | None = None
        self.views_seen = 0
        self.t_ns = 0
        self.decision = 0
        self.handlers: dict[str, Callable[[Json], None]] = {
            t.TOPIC_MAP_TILE: self._map_tile,
            t.TOPIC_GT_PATH: self._gt_path,
            t.TOPIC_GT_VIEWS: self._gt_views,
            t.TOPIC_DESTINATION: self._goal,
            t.TOPIC_ATTENTION: self._attention,
            t.TOPIC_START_POSE: self._start,
            t.TOPIC_TF: self._tf,
            t.TOPIC_RUN_PATH: self._path,
            t.TOPIC_RUN_VIEWS: self._view,
            t.TOPIC_OBSERVATION: self._observation(e.CAMERA_OBSERVATION),
            t.TOPIC_GT_OBSERVATION: self._observation(f"{e.CAMERA}/gt_observation"),
            t.TOPIC_AGENT_STEP: self._agent_step,
            t.TOPIC_AGENT_LOG: self._agent_log,
            t.TOPIC_AGENT_TARGET: self._target,
            t.TOPIC_LLM_EXCHANGE: self._exchange,
            t.TOPIC_CONTROL_STEP: self._control,
            t.TOPIC_OBSTACLES: self._obstacles,
            t.TOPIC_DIALOG: self._dialog,
        }

    # -- plumbing ----------------------------------------------------------------------
    def _decision_times(self) -> list[int]:
        for topic in _CLOCK_TOPICS:
            if self.log.topic_counts.get(topic):
                return sorted({t_ns for _, t_ns, _ in self.log.messages([topic])})
        return [0]

    def put(self, path: str, archetype: Any, static: bool = False) -> None:
        self.rec.log(path, archetype, static=static)
        self.rows[path] += 1

    def _at(self, t_ns: int) -> None:
        self.t_ns = t_ns
        self.decision = max(0, bisect.bisect_right(self.decision_times, t_ns) - 1)
        self.rec.set_time(e.DECISION_TIMELINE, sequence=self.decision)
        self.rec.set_time(e.SIM_TIMELINE, duration=np.timedelta64(t_ns, "ns"))

    def run(self) -> None:
        self._episode_info()
        for topic, t_ns, message in self.log.messages():
            handler = self.handlers.get(topic)
            if handler is not None:
                self._at(t_ns)
                handler(message)
        self._finish()

    def _strips2d(self, strips: list[scene.Strip], width_pt: float = 1.5) -> Any:
        rr = self.rr
        return rr.LineStrips2D(
            [self.frame.pixels(s.points) for s in strips],
            colors=[s.rgba for s in strips],
            radii=rr.Radius.ui_points(width_pt),
        )

    def _strips3d(self, strips: list[scene.Strip], width_pt: float = 1.5) -> Any:
        rr = self.rr
        return rr.LineStrips3D(
            [s.points for s in strips],
            colors=[s.rgba for s in strips],
            radii=rr.Radius.ui_points(width_pt),
        )

    # -- static content ------------------------------------------------------------------
    def _episode_info(self) -> None:
        run = self.log.run_metadata
        lines = [f"# {self.episode.split} {self.episode.episode_id}", ""]
        lines += [f"- map: {self.episode.map_name}", f"- log: {self.log.path}"]
        for key in ("system", "execution_mode", "stop_reason", "error", "config_digest"):
            if run.get(key):
                lines.append(f"- {key.replace('_', ' ')}: {run[key]}")
        if run.get("config"):
            lines += ["", "## Run configuration", "", text.fenced(run["config"].rstrip())]
        doc = self.rr.TextDocument("\n".join(lines) + "\n", media_type=self.rr.MediaType.MARKDOWN)
        self.put(e.EPISODE_INFO, doc, static=True)

    def _map_tile(self, message: Json) -> None:
        rr = self.rr
        data, media_type = scene.image_bytes(message)
        self.put(e.MAP_TILE, rr.EncodedImage(contents=data, media_type=media_type), static=True)
        # The tile is a downsampled copy: scale it up onto the map's own pixel grid.
        width, height = scene.image_size(data)
        if width and height:
            map_w, map_h = self.frame.size_px
            self.rec.log(
                e.MAP_TILE, rr.Transform3D(scale=[map_w / width, map_h / height, 1.0]), static=True
            )

    def _gt_path(self, message: Json) -> None:
        points = scene.pose_positions(message)
        strip = [scene.Strip(points, scene.GT_RGBA, False)]
        self.put(e.MAP_GT_ROUTE, self._strips2d(strip, 2.5), static=True)
        self.put(e.WORLD_GT_ROUTE, self._strips3d(strip, 2.5), static=True)

    def _gt_views(self, message: Json) -> None:
        self.put(
            e.MAP_GT_VIEWS, self._strips2d(scene.scene_strips(message, scene.GT_RGBA)), static=True
        )

    def _goal(self, message: Json) -> None:
        strips = scene.scene_strips(message)
        self.put(e.MAP_GOAL, self._strips2d(strips, 3.0), static=True)
        self.put(e.WORLD_GOAL, self._strips3d(strips, 3.0), static=True)

    def _attention(self, message: Json) -> None:
        self.put(e.MAP_ATTENTION, self._strips2d(scene.scene_strips(message)), static=True)

    def _start(self, message: Json) -> None:
        position = scene.xyz(message.get("pose", {}).get("position", {}))
        points = self.rr.Points2D(
            [self.frame.pixels(position)],
            labels=["start"],
            colors=[scene.GT_RGBA],
            radii=self.rr.Radius.ui_points(5.0),
        )
        self.put(e.MAP_START, points, static=True)

    # -- time series ---------------------------------------------------------------------
    def _tf(self, message: Json) -> None:
        if message.get("child_frame_id") != t.DRONE_FRAME:
            return  # the fixed drone -> camera mounting
        rr = self.rr
        position = scene.xyz(message.get("translation", {}))
        rotation = rr.Quaternion(xyzw=scene.quaternion_xyzw(message.get("rotation", {})))
        self.put(e.WORLD_DRONE, rr.Transform3D(translation=position, quaternion=rotation))
        dot = rr.Points2D(
            [self.frame.pixels(position)], colors=[scene.DRONE_RGBA], radii=rr.Radius.ui_points(4.0)
        )
        self.put(e.MAP_DRONE, dot)
        self.flight.add(position)

    def _path(self, _message: Json) -> None:
        self._log_flight()

    def _log_flight(self) -> None:
        points = self.flight.array()
        if len(points) < 1:
            return
        strip = [scene.Strip(points, scene.FLOWN_RGBA, False)]
        self.put(e.MAP_PATH, self._strips2d(strip, 2.0))
        self.put(e.WORLD_TRAJECTORY, self._strips3d(strip, 2.0))

    def _view(self, message: Json) -> None:
        strips = [
            scene.Strip(s.points, scene.FLOWN_RGBA, s.loop) for s in scene.scene_strips(message)
        ]
        if not strips:
            return
        # Views are logged in visiting order, as the log numbers them (visited_view_<k>).
        index = self.views_seen
        self.views_seen += 1
        self.put(f"{e.MAP_VIEWS}/{index}", self._strips2d(strips))
        self.put(f"{e.WORLD_VIEWS}/{index}", self._strips3d(strips))
        self.last_view = (strips[0], self.t_ns)

    def _observation(self, path: str) -> Callable[[Json], None]:
        def log_image(message: Json) -> None:
            data, media_type = scene.image_bytes(message)
            self.put(path, self.rr.EncodedImage(contents=data, media_type=media_type))

        return log_image

    def _agent_step(self, step: Json) -> None:
        rr = self.rr
        markdown = rr.MediaType.MARKDOWN
        t_s = self.t_ns / 1e9
        self.put(e.AGENT_STEP, rr.TextDocument(text.step_document(step, t_s), media_type=markdown))
        self.put(e.AGENT_HSD, rr.TextDocument(text.hsd_document(step), media_type=markdown))
        self.put(e.AGENT_MEMORY, rr.TextDocument(text.memory_document(step), media_type=markdown))
        sightings = (step.get("trace") or {}).get("sightings") or []
        found = scene.detections_by_view(sightings, self.image_px)
        for view in found:
            if view not in self.detection_views:
                self.detection_views.append(view)
                grid = rr.LineStrips2D(
                    scene.frame_and_grid(*self.image_px), colors=[(120, 120, 120, 255)]
                )
                self.rec.log(self._detections_path(view) + "/sectors", grid, static=True)
        for view in self.detection_views:
            boxes = found.get(view, scene.Detections([], []))
            self.put(
                self._detections_path(view),
                rr.Boxes2D(
                    array=np.asarray(boxes.boxes, np.float64).reshape(-1, 4),
                    array_format=rr.Box2DFormat.XYXY,
                    labels=boxes.labels,
                ),
            )

    @staticmethod
    def _detections_path(view: str) -> str:
        # "below" is the view under the drone: its boxes go over the observation image.
        if view == "below":
            return f"{e.CAMERA_OBSERVATION}/detections"
        return f"{e.CAMERA_DETECTIONS}/{view.replace(' ', '_').replace('+', '')}"

    def _agent_log(self, message: Json) -> None:
        self.put(e.AGENT_LOG, self.rr.TextLog(str(message.get("message", "")), level="INFO"))

    def _target(self, message: Json) -> None:
        position = scene.xyz(message.get("pose", {}).get("position", {}))
        target = self.rr.Points3D(
            [position],
            colors=[scene.TARGET_RGBA],
            radii=self.rr.Radius.ui_points(6.0),
            labels=["target"],
        )
        self.put(e.WORLD_TARGET, target)

    def _exchange(self, exchange: Json) -> None:
        rr = self.rr
        module = str(exchange.get("module") or "unknown").replace("/", "_")
        if module not in self.modules:
            self.modules.append(module)
        level = "ERROR" if exchange.get("error") else "INFO"
        self.put(e.LLM_LOG, rr.TextLog(text.exchange_line(exchange), level=level))
        doc = rr.TextDocument(text.exchange_document(exchange), media_type=rr.MediaType.MARKDOWN)
        self.put(f"{e.LLM}/{module}", doc)

    def _control(self, step: Json) -> None:
        self.signals.add(step, self.t_ns, self.decision)
        reference = step.get("reference_position_m")
        if isinstance(reference, list) and len(reference) == 3:
            point = self.rr.Points3D(
                [reference], colors=[scene.REFERENCE_RGBA], radii=self.rr.Radius.ui_points(3.0)
            )
            self.put(e.WORLD_REFERENCE, point)

    def _obstacles(self, message: Json) -> None:
        spheres = scene.scene_spheres(message)
        ellipsoids = self.rr.Ellipsoids3D(
            centers=spheres.centres,
            half_sizes=np.repeat(spheres.radii_m[:, None], 3, axis=1),
            colors=spheres.colours,
            fill_mode="solid",
        )
        self.put(e.WORLD_OBSTACLES, ellipsoids)

    def _dialog(self, turn: Json) -> None:
        self.dialog.append(turn)
        self.put(e.DIALOG, self.rr.TextLog(text.dialog_line(turn), level="INFO"))

    # -- the end -------------------------------------------------------------------------
    def _finish(self) -> None:
        rr = self.rr
        self._at(self.t_ns)
        self._log_flight()
        if self.last_view is not None:
            strip, t_ns = self.last_view
            self._at(t_ns)
            final = [scene.Strip(strip.points, scene.FINAL_VIEW_RGBA, strip.loop)]
            self.put(e.MAP_FINAL_VIEW, self._strips2d(final, 3.0))
        if self.dialog:
            doc = rr.TextDocument(
                text.dialog_document(self.dialog), media_type=rr.MediaType.MARKDOWN
            )
            self.put(f"{e.DIALOG}/all", doc, static=True)
        self.rec.log(
            f"{e.WORLD_DRONE}/body",
            rr.Boxes3D(half_sizes=[[2.0, 1.5, 0.4]], colors=[scene.DRONE_RGBA]),
            static=True,
        )
        self.rec.log(f"{e.WORLD_DRONE}/body", rr.TransformAxes3D(axis_length=6.0), static=True)
        for name, samples in self.signals.series.items():
            self.rec.send_columns(
                f"{e.CONTROL}/{name}",
                indexes=[
                    rr.TimeColumn(
                        e.SIM_TIMELINE, duration=np.asarray(samples.t_ns, "timedelta64[ns]")
                    ),
                    rr.TimeColumn(e.DECISION_TIMELINE, sequence=samples.decision),
                ],
                columns=rr.Scalars.columns(scalars=samples.values),
            )
            self.rows[f"{e.CONTROL}/{name}"] += len(samples.values)


def write_recording(ref: EpisodeLogRef, out: str | Path) -> RecordingSummary:
    """Build the recording of one episode and write it to ``out`` (``.rrd``), atomically."""
    rr = rerun_sdk()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    with RunLogStream(ref.path) as log:
        rec_id = recording_id(ref, log.run_metadata)
        rec = rr.RecordingStream(e.APPLICATION_ID, recording_id=rec_id)
        try:
            rec.save(tmp)
            system = log.run_metadata.get("system", "episode log")
            rec.send_recording_name(f"{system}: {ref.split}/{ref.episode_id}")
            recorder = _Recorder(rr, rec, log)
            recorder.run()
            rec.send_blueprint(episode_blueprint(rr, recorder.modules, recorder.detection_views))
            rec.flush()
            rec.disconnect()  # writes the footer: the file is complete only after this
            tmp.replace(out)
        except BaseException:
            rec.disconnect()
            tmp.unlink(missing_ok=True)
            raise
    return RecordingSummary(out, ref, rec_id, len(recorder.decision_times), dict(recorder.rows))
