"""The timeless part of a recording: the episode card, the map and the ground truth.

The map tile stored in the log is a downsampled copy of the map: in 2-D it is scaled up
onto the map's own pixel grid, in 3-D it is laid on the ground (z = 0) as a textured
rectangle covering the whole map in ENU metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.records import Episode
from skyvln_eval.converters import topics as t
from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer import scene, text
from skyvln_eval.viewer.canvas import Canvas

Json = Mapping[str, Any]
#: The ground texture sits just below the view squares drawn at z = 0.
_GROUND_Z_M = -0.5


#: Counts of the run metadata that explain a 'degraded' or 'error' status (written by the
#: runner; absent from logs of older runs), with what each counts.
STATUS_COUNTS = (
    ("fallback_decisions", "fallback decision(s)"),
    ("module_failures", "module failure(s)"),
    ("llm_failed_calls", "failed LLM call(s)"),
    ("llm_parse_failures", "unusable LLM answer(s)"),
)


def status_line(run: Mapping[str, str]) -> str | None:
    """The episode's status (``ok``, ``degraded``, ``error``) as the card shows it: with the
    counts that explain a status other than ok, where the run metadata has them; ``None``
    for a log without one (an episode log, converted from the dataset: nothing was run)."""
    status = run.get("status")
    if not status:
        return None
    counts = []
    if status != "ok":
        for key, what in STATUS_COUNTS:
            value = run.get(key, "")
            if value.isdigit() and int(value):
                counts.append(f"{value} {what}")
    said = ", ".join(counts)
    if said and run.get("llm_calls", "").isdigit():
        said += f"; {run['llm_calls']} LLM call(s) in all"
    return f"- status: **{status}**" + (f" ({said})" if said else "")


def episode_card_text(episode: Episode, run: Mapping[str, str], path: Path) -> str:
    """The episode card: what the episode is, which log, and what the run said of it."""
    lines = [f"# {episode.split} {episode.episode_id}", ""]
    task = "ANDH-Full (the whole trajectory)" if episode.mode == "andh-full" else "ANDH"
    lines += [f"- mode: {task}", f"- map: {episode.map_name}", f"- log: {path}"]
    if run.get("system"):
        lines.append(f"- system: {run['system']}")
    # The status first after the system: a degraded or failed episode must not read as a
    # result that went as planned.
    if (status := status_line(run)) is not None:
        lines.append(status)
    for key in ("execution_mode", "stop_reason", "error", "config_digest"):
        if run.get(key):
            lines.append(f"- {key.replace('_', ' ')}: {run[key]}")
    if run.get("config"):
        lines += ["", "## Run configuration", "", text.fenced(run["config"].rstrip())]
    return "\n".join(lines) + "\n"


def episode_card(canvas: Canvas, episode: Episode, run: Mapping[str, str], path: Path) -> None:
    canvas.markdown(e.EPISODE_INFO, episode_card_text(episode, run, path), static=True)


def map_tile(canvas: Canvas, message: Json) -> None:
    rr = canvas.rr
    data, media_type = scene.image_bytes(message)
    canvas.put(e.MAP_TILE, rr.EncodedImage(contents=data, media_type=media_type), static=True)
    rgb = scene.decode_rgb(data)  # the small tile only: images of the flight stay encoded
    if rgb is None:
        return
    height, width = rgb.shape[:2]
    map_w, map_h = canvas.frame.size_px
    scale = rr.Transform3D(scale=[map_w / width, map_h / height, 1.0])
    canvas.rec.log(e.MAP_TILE, scale, static=True)
    (lat0, lng0), (lat1, lng1) = (
        canvas.frame.georef.gps_botm_left,
        canvas.frame.georef.gps_top_right,
    )
    east_m, north_m = (lng1 - lng0) * METERS_PER_DEGREE, (lat1 - lat0) * METERS_PER_DEGREE
    z = _GROUND_Z_M
    ground = rr.Mesh3D(
        vertex_positions=[[0, 0, z], [east_m, 0, z], [east_m, north_m, z], [0, north_m, z]],
        triangle_indices=[[0, 1, 2], [0, 2, 3]],
        # The image's top-left pixel is the map's north-west corner.
        vertex_texcoords=[[0, 1], [1, 1], [1, 0], [0, 0]],
        albedo_texture=rgb,
    )
    canvas.put(e.WORLD_MAP, ground, static=True)


def gt_path(canvas: Canvas, message: Json) -> None:
    strip = [scene.Strip(scene.pose_positions(message), scene.GT_RGBA, False)]
    canvas.put(e.MAP_GT_ROUTE, canvas.strips2d(strip, 2.5), static=True)
    canvas.put(e.WORLD_GT_ROUTE, canvas.strips3d(strip, 2.5), static=True)


def gt_views(canvas: Canvas, message: Json) -> None:
    strips = scene.scene_strips(message, scene.GT_RGBA)
    canvas.put(e.MAP_GT_VIEWS, canvas.strips2d(strips), static=True)


def goal(canvas: Canvas, message: Json) -> None:
    strips = scene.scene_strips(message)
    canvas.put(e.MAP_GOAL, canvas.strips2d(strips, 3.0), static=True)
    canvas.put(e.WORLD_GOAL, canvas.strips3d(strips, 3.0), static=True)


def attention(canvas: Canvas, message: Json) -> None:
    canvas.put(e.MAP_ATTENTION, canvas.strips2d(scene.scene_strips(message)), static=True)


def start_pose(canvas: Canvas, message: Json) -> None:
    position = scene.xyz(message.get("pose", {}).get("position", {}))
    rr = canvas.rr
    points = rr.Points2D(
        np.asarray([canvas.frame.pixels(position)]),
        labels=["start"],
        colors=[scene.GT_RGBA],
        radii=rr.Radius.ui_points(5.0),
    )
    canvas.put(e.MAP_START, points, static=True)


def drone_body(canvas: Canvas) -> None:
    """A box with axes that moves with the ``world/drone`` transform (and tilts with the
    airframe's, where a flown run's log has it)."""
    rr = canvas.rr
    body = e.WORLD_DRONE_BODY
    canvas.rec.log(
        body, rr.Boxes3D(half_sizes=[[2.0, 1.5, 0.4]], colors=[scene.DRONE_RGBA]), static=True
    )
    canvas.rec.log(body, rr.TransformAxes3D(axis_length=6.0), static=True)


#: Handlers of the static topics, by topic name (see :mod:`skyvln_eval.converters.topics`).
HANDLERS = {
    t.TOPIC_MAP_TILE: map_tile,
    t.TOPIC_GT_PATH: gt_path,
    t.TOPIC_GT_VIEWS: gt_views,
    t.TOPIC_DESTINATION: goal,
    t.TOPIC_ATTENTION: attention,
    t.TOPIC_START_POSE: start_pose,
}
