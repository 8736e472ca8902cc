"""Build the Rerun recording of one episode from its run MCAP, streaming.

:func:`write_recording` opens the log (:class:`~.logs.RunLogStream`), then logs every
message in log-time order: static topics as timeless data (:mod:`.static_content`), the
rest on the ``decision`` and ``sim_time`` timelines. It writes an ``.rrd`` file under a
temporary name, renamed into place when complete. The log is the only source: nothing is
recomputed from the dataset or the harness. Entity paths are in :mod:`.entities`.
"""

from __future__ import annotations

import binascii
import hashlib
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import yaml

from skyvln_eval.avdn import Episode
from skyvln_eval.converters import topics as t
from skyvln_eval.errors import McapLogError
from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer import scene, static_content, text
from skyvln_eval.viewer.blueprint import Focus, episode_blueprint
from skyvln_eval.viewer.canvas import Canvas
from skyvln_eval.viewer.deps import rerun_sdk
from skyvln_eval.viewer.logs import EpisodeLogRef, RunLogStream
from skyvln_eval.viewer.signals import ControlSignals

Json = Mapping[str, Any]
#: Topics whose message times are the decisions: agent steps (run logs), else one GPS fix
#: per ground-truth view (episode logs).
_CLOCK_TOPICS = (t.TOPIC_AGENT_STEP, t.TOPIC_GPS)
#: What flows between decisions: on the decision timeline only at a decision's time.
_CONTINUOUS_TOPICS = frozenset({t.TOPIC_TF, t.TOPIC_CONTROL_STEP, t.TOPIC_OBSTACLES})
_DEFAULT_IMAGE_PX = 224


@dataclass(frozen=True)
class RecordingSummary:
    """What one recording holds: where it was written and the rows logged per entity.

    ``run_log`` says whether it was built from a run log (an agent flew it) or from an
    episode log (``convert``: the ground truth only); ``decisions`` counts the agent's
    decisions (0 in an episode log) and ``gt_views`` an episode log's ground-truth views
    (0 in a run log, whose ground truth is drawn, not stepped through).
    """

    path: Path
    episode: EpisodeLogRef
    recording_id: str
    decisions: int
    rows: dict[str, int]
    run_log: bool
    gt_views: int
    #: Decisions at a time another one has too (logs of older runs): merged on the
    #: decision timeline.
    merged_decisions: int = 0


def recording_id(ref: EpisodeLogRef, run: Mapping[str, str], mode: str) -> str:
    """Unique per log file: the split, mode, episode and run configuration, then a short
    hash of the log's path, so several runs, an episode's ANDH and ANDH-Full logs, and two
    runs of one configuration (a copy, or the same run made twice) can be opened together
    (two such runs were one recording, every row twice, their paths drawn over each other)."""
    digest = run.get("config_digest", "episode-log")
    where = hashlib.sha256(str(ref.path.resolve()).encode()).hexdigest()[:8]
    return f"{ref.split}/{mode}/{ref.episode_id}@{digest}:{where}"


def application_id(rec_id: str) -> str:
    """The recording's application id: Rerun takes letters, digits, '-', '_' and ':' in
    one (it rewrites others with a warning on stderr, one per recording, and a hash
    appended), so the recording id's '/' and '@' become '-'."""
    return f"{e.APPLICATION_ID}:{re.sub(r'[^A-Za-z0-9_:-]', '-', rec_id)}"


def recording_name(ref: EpisodeLogRef, run: Mapping[str, str], mode: str) -> str:
    """The name the viewer lists: the system, the episode and, unless ok, its status (an
    episode that ended in error must not look like one that went as planned)."""
    system = run.get("system", "episode log")
    status = run.get("status", "")
    flagged = f" [{status.upper()}]" if status and status != "ok" else ""
    return f"{system}: {ref.split}/{mode}/{ref.episode_id}{flagged}"


def _image_px(run: Mapping[str, str]) -> tuple[int, int]:
    """The agent's camera image size (for HSD sector boxes), from the run's resolved config."""
    try:
        config = yaml.safe_load(run.get("config", "")) or {}
        size = int(config["sensors"]["image_px"])
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        size = _DEFAULT_IMAGE_PX
    return size, size


def _decision_times(log: RunLogStream) -> list[int]:
    for topic in _CLOCK_TOPICS:
        if log.topic_counts.get(topic):
            return sorted({t_ns for _, t_ns, _ in log.messages([topic])})
    return [0]


class _Recorder:
    """Logs one episode's time-ordered messages onto a canvas (one handler per topic)."""

    def __init__(self, canvas: Canvas, image_px: tuple[int, int], run_log: bool) -> None:
        self.canvas = canvas
        #: A run's log (an agent flew it), not an episode log (its poses are the GT route).
        self.run_log = run_log
        #: Per LLM module, the decision time of its last exchange and the documents of its
        #: exchanges at that time: a first answer and its repair are shown together.
        self.exchanges: dict[str, tuple[int, list[str]]] = {}
        self.rr: ModuleType = canvas.rr
        self.image_px = image_px
        self.flight = scene.Flight()
        self.signals = ControlSignals()
        self.dialog: list[Json] = []
        self.modules: list[str] = []
        self.detection_views: list[str] = []
        self.last_view: tuple[scene.Strip, int] | None = None
        self.views_seen = 0
        #: Decisions the decision timeline merged with another at the same time.
        self.merged_decisions = 0
        self.horizon_shown = False
        #: The heading frame's last rotation (x, y, z, w): the body's tilt is relative to it.
        self.heading_xyzw = [0.0, 0.0, 0.0, 1.0]
        self.handlers: dict[str, Callable[[Json], None]] = {
            t.TOPIC_TF: self._tf,
            t.TOPIC_RUN_PATH: lambda _: self._flight_so_far(),
            t.TOPIC_RUN_VIEWS: self._view,
            t.TOPIC_OBSERVATION: self._image(e.CAMERA_OBSERVATION),
            t.TOPIC_CAMERA_VIEWS: self._camera_view,
            t.TOPIC_GT_OBSERVATION: self._image(e.CAMERA_GT_OBSERVATION),
            t.TOPIC_AGENT_STEP: self._agent_step,
            t.TOPIC_AGENT_LOG: self._agent_log,
            t.TOPIC_AGENT_TARGET: self._target,
            t.TOPIC_LLM_EXCHANGE: self._exchange,
            t.TOPIC_CONTROL_STEP: self._control,
            t.TOPIC_OBSTACLES: self._obstacles,
            t.TOPIC_DIALOG: self._dialog,
        }

    def on(self, topic: str, t_ns: int, message: Json) -> None:
        if (static := static_content.HANDLERS.get(topic)) is not None:
            static(self.canvas, message)
        elif (handler := self.handlers.get(topic)) is not None:
            self.canvas.at(t_ns, continuous=topic in _CONTINUOUS_TOPICS)
            handler(message)

    def _tf(self, message: Json) -> None:
        child = message.get("child_frame_id")
        if child == t.BODY_FRAME:  # a flown run's airframe: the box tilts as it did
            self._tilt(scene.quaternion_xyzw(message.get("rotation", {})))
        if child != t.DRONE_FRAME:
            return  # the fixed drone -> camera mounting
        rr, canvas = self.rr, self.canvas
        position = scene.xyz(message.get("translation", {}))
        self.heading_xyzw = scene.quaternion_xyzw(message.get("rotation", {}))
        rotation = rr.Quaternion(xyzw=self.heading_xyzw)
        canvas.put(e.WORLD_DRONE, rr.Transform3D(translation=position, quaternion=rotation))
        dot = rr.Points2D(
            np.asarray([canvas.frame.pixels(position)]),
            colors=[scene.DRONE_RGBA],
            radii=rr.Radius.ui_points(4.0),
        )
        canvas.put(e.MAP_DRONE, dot)
        self.flight.add(position)

    def _tilt(self, body_xyzw: list[float]) -> None:
        """The airframe's box and axes under the level heading frame (``world/drone``,
        whose transform at the same time came first): the body's rotation relative to it."""
        relative = scene.relative_rotation_xyzw(self.heading_xyzw, body_xyzw)
        self.canvas.put(
            e.WORLD_DRONE_BODY, self.rr.Transform3D(quaternion=self.rr.Quaternion(xyzw=relative))
        )

    def _flight_so_far(self) -> None:
        points = self.flight.array()
        if len(points) and self.run_log:  # an episode log's poses are the GT route, drawn already
            strip = [scene.Strip(points, scene.FLOWN_RGBA, False)]
            self.canvas.put(e.MAP_PATH, self.canvas.strips2d(strip, 2.0))
            self.canvas.put(e.WORLD_TRAJECTORY, self.canvas.strips3d(strip, 2.0))

    def _view(self, message: Json) -> None:
        strips = [
            scene.Strip(s.points, scene.FLOWN_RGBA, s.loop) for s in scene.scene_strips(message)
        ]
        if not strips:
            return
        # Views come in visiting order, as the log numbers them (visited_view_<k>).
        index, self.views_seen = self.views_seen, self.views_seen + 1
        self.canvas.put(f"{e.MAP_VIEWS}/{index}", self.canvas.strips2d(strips))
        self.canvas.put(f"{e.WORLD_VIEWS}/{index}", self.canvas.strips3d(strips))
        self.last_view = (strips[0], self.canvas.t_ns)

    def _image(self, path: str) -> Callable[[Json], None]:
        return lambda message: self._put_image(path, message)

    def _put_image(self, path: str, message: Json) -> None:
        data, media_type = scene.image_bytes(message)  # passed on encoded
        self.canvas.put(path, self.rr.EncodedImage(contents=data, media_type=media_type))

    def _add_view(self, view: str) -> None:
        """A camera view gets its place (and the HSD sector grid) the first time it shows."""
        if view in self.detection_views:
            return
        self.detection_views.append(view)
        grid = scene.frame_and_grid(*self.image_px)
        sectors = self.rr.LineStrips2D(grid, colors=[(120, 120, 120, 255)])
        self.canvas.rec.log(f"{e.camera_view(view)}/sectors", sectors, static=True)

    def _camera_view(self, message: Json) -> None:
        frame = str(message.get("frame_id", ""))
        view = frame.removeprefix(t.CAMERA_VIEW_FRAME_PREFIX) or "unnamed"
        self._add_view(view)
        self._put_image(f"{e.camera_view(view)}/image", message)

    def _agent_step(self, step: Json) -> None:
        canvas = self.canvas
        canvas.markdown(e.AGENT_STEP, text.step_document(step, canvas.t_ns / 1e9))
        canvas.markdown(e.AGENT_HSD, text.hsd_document(step))
        canvas.markdown(e.AGENT_MEMORY, text.memory_document(step))
        sightings = (step.get("trace") or {}).get("sightings") or []
        found = scene.detections_by_view(sightings, self.image_px)
        rr = self.rr
        for view in found:
            self._add_view(view)
        for view in self.detection_views:  # every view each decision: old boxes disappear
            boxes = found.get(view, scene.Detections([], []))
            array = np.asarray(boxes.boxes, np.float64).reshape(-1, 4)
            fmt = rr.Box2DFormat.XYXY
            canvas.put(
                e.camera_view(view),
                rr.Boxes2D(array=array, array_format=fmt, labels=boxes.labels),
            )

    def _agent_log(self, message: Json) -> None:
        line = self.rr.TextLog(str(message.get("message", "")), level="INFO")
        self.canvas.put(e.AGENT_LOG, line)

    def _target(self, message: Json) -> None:
        position = scene.xyz(message.get("pose", {}).get("position", {}))
        target = self.rr.Points3D(
            [position],
            colors=[scene.TARGET_RGBA],
            radii=self.rr.Radius.ui_points(6.0),
            labels=["target"],
        )
        self.canvas.put(e.WORLD_TARGET, target)

    def _exchange(self, exchange: Json) -> None:
        module = str(exchange.get("module") or "unknown").replace("/", "_")
        if module not in self.modules:
            self.modules.append(module)
        level = "ERROR" if exchange.get("error") else "INFO"
        self.canvas.put(e.LLM_LOG, self.rr.TextLog(text.exchange_line(exchange), level=level))
        # One document per module and decision: several exchanges at one time (HSD's calls,
        # an answer and its repair) would each hide the one before.
        t_ns, documents = self.exchanges.get(module, (-1, []))
        if t_ns != self.canvas.t_ns:
            t_ns, documents = self.canvas.t_ns, []
        documents.append(text.exchange_document(exchange))
        self.exchanges[module] = (t_ns, documents)
        self.canvas.markdown(f"{e.LLM}/{module}", "\n---\n\n".join(documents))

    def _control(self, step: Json) -> None:
        self.signals.add(step, self.canvas.t_ns)
        reference = step.get("reference_position_m")
        if isinstance(reference, list) and len(reference) == 3:
            point = self.rr.Points3D(
                [reference], colors=[scene.REFERENCE_RGBA], radii=self.rr.Radius.ui_points(3.0)
            )
            self.canvas.put(e.WORLD_REFERENCE, point)
        horizon = step.get("predicted_positions_m")
        if isinstance(horizon, list) and horizon:
            strip = [scene.Strip(np.asarray(horizon, dtype=np.float64), scene.HORIZON_RGBA, False)]
            self.canvas.put(e.WORLD_HORIZON, self.canvas.strips3d(strip, 1.5))
            self.horizon_shown = True
        elif self.horizon_shown:  # no prediction this step (a fallback): no stale horizon
            self.canvas.put(e.WORLD_HORIZON, self.rr.Clear(recursive=False))
            self.horizon_shown = False

    def _obstacles(self, message: Json) -> None:
        spheres = scene.scene_spheres(message)
        ellipsoids = self.rr.Ellipsoids3D(
            centers=spheres.centres,
            half_sizes=np.repeat(spheres.radii_m[:, None], 3, axis=1),
            colors=spheres.colours,
            fill_mode="solid",
        )
        self.canvas.put(e.WORLD_OBSTACLES, ellipsoids)

    def _dialog(self, turn: Json) -> None:
        self.dialog.append(turn)
        self.canvas.put(e.DIALOG, self.rr.TextLog(text.dialog_line(turn), level="INFO"))

    def finish(self) -> None:
        """The whole flight, the final view, the dialog and the control signals."""
        canvas, rr = self.canvas, self.rr
        self._flight_so_far()
        if self.last_view is not None:
            strip, t_ns = self.last_view
            canvas.at(t_ns)
            final = [scene.Strip(strip.points, scene.FINAL_VIEW_RGBA, strip.loop)]
            canvas.put(e.MAP_FINAL_VIEW, canvas.strips2d(final, 3.0))
        if self.dialog:
            canvas.markdown(f"{e.DIALOG}/all", text.dialog_document(self.dialog), static=True)
        static_content.drone_body(canvas)
        for name, samples in self.signals.series.items():
            # On simulated time only: the flight between decisions is not a decision's
            # (on the decision timeline, each segment's samples were stacked on one index,
            # and decision k read the state at the end of its segment, not when it was made).
            canvas.rec.send_columns(
                f"{e.CONTROL}/{name}",
                indexes=[
                    rr.TimeColumn(
                        e.SIM_TIMELINE, duration=np.asarray(samples.t_ns, "timedelta64[ns]")
                    )
                ],
                columns=rr.Scalars.columns(scalars=samples.values),
            )
            canvas.rows[f"{e.CONTROL}/{name}"] += len(samples.values)

    def focus(self) -> Focus | None:
        """Where the 3-D view should look: the flight, from behind its start and above."""
        points = self.flight.array()
        if not len(points):
            return None
        centre = points.mean(axis=0)
        reach = max(80.0, float(np.ptp(points[:, :2], axis=0).max()))
        eye = centre + np.array([-0.5, -1.0, 0.9]) * reach
        return Focus(eye.tolist(), centre.tolist())


def _record(rr: ModuleType, rec: Any, log: RunLogStream, episode: Episode) -> _Recorder:
    canvas = Canvas(rr, rec, e.MapFrame(episode.georef), _decision_times(log))
    static_content.episode_card(canvas, episode, log.run_metadata, log.path)
    recorder = _Recorder(canvas, _image_px(log.run_metadata), t.RUN_METADATA in log.metadata)
    for topic, t_ns, message in log.messages():
        try:
            recorder.on(topic, t_ns, message)
        except (ValueError, TypeError, KeyError, IndexError, binascii.Error) as error:
            raise McapLogError(
                str(log.path),
                f"its {topic} message at {t_ns / 1e9:g} s cannot be shown "
                f"({type(error).__name__}: {error}); `skyvln-eval validate` checks the log",
            ) from None
    recorder.finish()
    run = log.run_metadata
    if run.get("status") in ("error", "degraded"):  # said where the eye lands, at the end
        canvas.put(
            e.AGENT_LOG,
            rr.TextLog(
                f"the episode ended {run['status']}: {run.get('error') or 'see the episode tab'}",
                level="ERROR" if run["status"] == "error" else "WARN",
            ),
        )
    blueprint = episode_blueprint(
        rr, recorder.modules, recorder.detection_views, recorder.focus(), recorder.run_log
    )
    # Logs of runs from before every segment took a control step may have two decisions
    # at one time: the timeline cannot tell them apart, so it says so.
    decisions = log.topic_counts.get(t.TOPIC_AGENT_STEP, 0)
    recorder.merged_decisions = max(0, decisions - len(canvas.decision_times_ns))
    if recorder.merged_decisions:
        merged = recorder.merged_decisions
        canvas.at(canvas.decision_times_ns[0])
        canvas.put(
            e.AGENT_LOG,
            rr.TextLog(
                f"{merged} decision(s) share their time with another: the decision timeline "
                "shows each such group as one (sim_time keeps their order)",
                level="WARN",
            ),
        )
    rec.send_blueprint(blueprint)
    return recorder


def write_recording(ref: EpisodeLogRef, out: str | Path) -> RecordingSummary:
    """Build the recording of one episode and write it to ``out`` (``.rrd``), atomically."""
    rr = rerun_sdk()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    with RunLogStream(ref.path) as log:
        # Counted from the log, not from the clock: a run that raised before its first
        # decision has none, and an episode log's clock ticks are ground-truth views.
        run_log = t.RUN_METADATA in log.metadata
        decisions = log.topic_counts.get(t.TOPIC_AGENT_STEP, 0)
        gt_views = 0 if run_log else log.topic_counts.get(t.TOPIC_GPS, 0)
        episode = log.episode()  # its records parsed once: read from the metadata
        rec_id = recording_id(ref, log.run_metadata, episode.mode)
        # An application per recording: the viewer keeps one layout per application, and
        # episodes differ in theirs (their LLM tabs, where the 3-D eye looks).
        rec = rr.RecordingStream(application_id(rec_id), recording_id=rec_id)
        rec.set_log_time_enabled(False)  # the two timelines are simulated time and decisions
        try:
            rec.save(tmp)
            rec.send_recording_name(recording_name(ref, log.run_metadata, episode.mode))
            recorder = _record(rr, rec, log, episode)
            rec.flush()
            rec.disconnect()  # writes the footer: the file is complete only after this
            tmp.replace(out)
        except BaseException:
            rec.disconnect()
            tmp.unlink(missing_ok=True)
            raise
    rows = dict(recorder.canvas.rows)
    return RecordingSummary(
        out, ref, rec_id, decisions, rows, run_log, gt_views, recorder.merged_decisions
    )
