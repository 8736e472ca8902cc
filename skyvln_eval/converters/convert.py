"""Convert one AVDN episode into an episode log: a pure function of (episode, world, writer).

Layout of an episode log (names in :mod:`skyvln_eval.converters.topics`):

- metadata ``skyvln_eval.episode``: episode id, split, mode, map, the source record(s)
  as parsed (JSON list: every key in its order, every number exactly, as compact JSON,
  not the file's own spacing, escapes or float spelling), toolkit and format versions,
  clock step, options;
- static content at log time 0, written first: the downsampled map tile, the GT path
  (``PosesInFrame``), GT view squares, destination and attention circles
  (``SceneUpdate`` lines in the ``map`` frame, ENU metres), the start pose, and the fixed
  ``drone`` -> ``camera`` transform;
- then, for GT view k at ``k * clock_step_ns``: the ``map`` -> ``drone`` transform (drone at
  height edge / 2 above the view centre, yaw from the official view heading), the GPS fix
  of the view centre (its ``altitude`` is that height above ground, m), the 224 x 224 GT
  observation, and the dialog turns of a round at the first view of that round (ANDH
  gives the whole dialog at time 0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any, Final, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

import skyvln_eval
from skyvln_eval.avdn import (
    METERS_PER_DEGREE,
    DialogTurn,
    Episode,
    observe_view,
    view_centre,
)
from skyvln_eval.converters import messages as fx
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.writer import McapLogWriter, encode_json
from skyvln_eval.errors import ConfigError, DataError
from skyvln_eval.frames import ViewPose, latlng_to_enu, view_to_pose
from skyvln_eval.worlds import WorldTile

#: One GT view per second on the deterministic episode clock.
CLOCK_STEP_NS: Final = 1_000_000_000
#: Segments of the polygon drawn for an attention circle.
CIRCLE_SEGMENTS: Final = 32

START_RGBA: Final = (0.1, 0.8, 0.2, 1.0)
VIEW_RGBA: Final = (0.2, 0.5, 1.0, 0.8)
END_RGBA: Final = (1.0, 0.25, 0.2, 1.0)
DESTINATION_RGBA: Final = (1.0, 0.8, 0.0, 1.0)
ATTENTION_RGBA: Final = (1.0, 0.0, 1.0, 0.9)

ImageFormat = Literal["jpeg", "png"]


@dataclass(frozen=True)
class ConvertOptions:
    """What goes into an episode log besides the episode itself.

    ``observations``: write the GT observation at each view (needs the world).
    ``map_tile_max_side_px``: longest side of the downsampled map tile (0: no tile).
    """

    observations: bool = True
    image_format: ImageFormat = "jpeg"
    jpeg_quality: int = 90
    map_tile_max_side_px: int = 384

    def as_metadata(self) -> dict[str, str]:
        return {
            "observations": "true" if self.observations else "false",
            "image_format": self.image_format,
            "jpeg_quality": str(self.jpeg_quality),
            "map_tile_max_side_px": str(self.map_tile_max_side_px),
        }


DEFAULT_OPTIONS: Final = ConvertOptions()


def encode_image(image: NDArray[Any], image_format: ImageFormat, jpeg_quality: int) -> bytes:
    """BGR image to JPEG or PNG bytes (deterministic for a given OpenCV build)."""
    if image_format == "jpeg":
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    elif image_format == "png":
        ok, buf = cv2.imencode(".png", image)
    else:
        raise ConfigError(f"image format must be 'jpeg' or 'png', not {image_format!r}")
    if not ok:
        raise ConfigError(f"OpenCV could not encode a {image.shape} image as {image_format}")
    return buf.tobytes()


@lru_cache(maxsize=4)
def _map_tile(world: WorldTile, max_side_px: int, image_format: ImageFormat, quality: int) -> bytes:
    # Every episode of a map shares its tile: encode it once per world (worlds hash by
    # identity, and a process converts a map's episodes together).
    height, width = world.shape
    scale = min(1.0, max_side_px / max(height, width))
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    small = cv2.resize(world.bgr, size, interpolation=cv2.INTER_AREA)
    return encode_image(small, image_format, quality)


def episode_rounds(episode: Episode) -> int:
    """Dialog rounds the episode covers: ANDH round k sees rounds 1..k."""
    return episode.records[-1].round_index


def episode_metadata(
    episode: Episode, options: ConvertOptions, clock_step_ns: int | None = CLOCK_STEP_NS
) -> dict[str, str]:
    """The ``skyvln_eval.episode`` metadata record: everything needed to rebuild the episode.

    ``options`` and ``clock_step_ns`` must describe the log written: what it holds, and
    the time between its views (None: no fixed step, the key is left out).
    """
    records = [record.to_json_dict() for record in episode.records]
    try:
        # The records as parsed, as compact JSON: floats keep their shortest repr, so
        # re-parsing gives the same values.
        # Strict (no NaN) UTF-8, as every message: validation refuses a record that strict
        # JSON cannot hold (NaN, half a surrogate pair).
        records_json = encode_json(records).decode("utf-8")
    except ValueError as exc:  # a record made in Python, not read by the validator
        raise DataError(
            f"episode {episode.episode_id}: records are not strict JSON: {exc}"
        ) from exc
    clock = {} if clock_step_ns is None else {"clock_step_ns": str(clock_step_ns)}
    return {
        "format": t.EPISODE_FORMAT,
        "format_version": str(t.EPISODE_FORMAT_VERSION),
        "toolkit_version": skyvln_eval.__version__,
        "episode_id": episode.episode_id,
        "split": episode.split,
        "mode": episode.mode,
        "map_name": episode.map_name,
        "rounds": str(episode_rounds(episode)),
        "gt_views": str(len(episode.gt_path_corners)),
        **clock,
        "foxglove_schemas": f"{t.FOXGLOVE_SCHEMAS_PACKAGE}@{t.FOXGLOVE_SCHEMAS_VERSION}",
        "records": records_json,
        **options.as_metadata(),
    }


def _ground_loop(corners_latlng: NDArray[np.float64], episode: Episode) -> list[list[float]]:
    enu = latlng_to_enu(corners_latlng, episode.georef)
    return [[float(x), float(y), 0.0] for x, y in enu]


def _view_lines(episode: Episode) -> list[fx.Json]:
    views = episode.gt_path_corners
    last = len(views) - 1
    lines = []
    for k, corners in enumerate(views):
        rgba = START_RGBA if k == 0 else END_RGBA if k == last else VIEW_RGBA
        lines.append(fx.line(_ground_loop(corners, episode), rgba, loop=True, width_px=2.0))
    return lines


def _attention_lines(episode: Episode) -> list[fx.Json]:
    """Attention circles as polygons; radii are resized-map pixels of lat_ratio degrees."""
    georef = episode.georef
    angles = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS, endpoint=False)
    lines = []
    for circle in episode.records[-1].attention_list:
        x0, y0 = latlng_to_enu(circle.centre, georef)
        radius_m = circle.radius_px * georef.lat_ratio * METERS_PER_DEGREE
        points = [[x0 + radius_m * math.cos(a), y0 + radius_m * math.sin(a), 0.0] for a in angles]
        lines.append(fx.line(points, ATTENTION_RGBA, loop=True, width_px=2.0))
    return lines


def _round_start_times(episode: Episode) -> dict[int, int]:
    """Log time at which each round's dialog is given, by round index."""
    if episode.mode == "andh":
        return {turn.round_index: 0 for turn in episode.dialog()}
    return {index: view * CLOCK_STEP_NS for index, view in episode.round_starts().items()}


def _dialog_by_view(episode: Episode) -> dict[int, list[DialogTurn]]:
    starts = _round_start_times(episode)
    by_view: dict[int, list[DialogTurn]] = {}
    for turn in episode.dialog():
        by_view.setdefault(starts[turn.round_index] // CLOCK_STEP_NS, []).append(turn)
    return by_view


def write_static_content(
    episode: Episode,
    world: WorldTile | None,
    poses: Sequence[ViewPose],
    writer: McapLogWriter,
    options: ConvertOptions,
) -> None:
    meta = {"episode_id": episode.episode_id}
    if world is not None and options.map_tile_max_side_px > 0:
        tile = _map_tile(
            world, options.map_tile_max_side_px, options.image_format, options.jpeg_quality
        )
        writer.write(
            t.TOPIC_MAP_TILE,
            t.COMPRESSED_IMAGE,
            fx.compressed_image(0, t.MAP_TILE_FRAME, tile, options.image_format),
            0,
        )
    path = [fx.pose(p.x_m, p.y_m, p.z_m, p.yaw_rad) for p in poses]
    writer.write(t.TOPIC_GT_PATH, t.POSES_IN_FRAME, fx.poses_in_frame(0, t.MAP_FRAME, path), 0)
    views = fx.scene_update(0, t.MAP_FRAME, "gt_views", _view_lines(episode), meta)
    writer.write(t.TOPIC_GT_VIEWS, t.SCENE_UPDATE, views, 0)
    if episode.destination is not None:
        dest = fx.line(_ground_loop(episode.destination, episode), DESTINATION_RGBA, True, 3.0)
        update = fx.scene_update(0, t.MAP_FRAME, "destination", [dest], meta)
        writer.write(t.TOPIC_DESTINATION, t.SCENE_UPDATE, update, 0)
    attention = _attention_lines(episode)
    if attention:
        update = fx.scene_update(0, t.MAP_FRAME, "attention", attention, meta)
        writer.write(t.TOPIC_ATTENTION, t.SCENE_UPDATE, update, 0)
    writer.write(t.TOPIC_START_POSE, t.POSE_IN_FRAME, fx.pose_in_frame(0, t.MAP_FRAME, path[0]), 0)
    camera = fx.frame_transform(
        0, t.DRONE_FRAME, t.CAMERA_FRAME, fx.vector3(0, 0, 0), fx.CAMERA_FROM_DRONE_QUATERNION
    )
    writer.write(t.TOPIC_TF, t.FRAME_TRANSFORM, camera, 0)


def convert_episode(
    episode: Episode,
    world: WorldTile | None,
    writer: McapLogWriter,
    options: ConvertOptions = DEFAULT_OPTIONS,
) -> None:
    """Write one episode into an open writer (see the module docstring for the layout).

    ``world`` gives the map tile and the GT observations; with ``None`` (or
    ``options.observations`` false) the log holds no images.
    """
    if world is not None and world.map_name != episode.map_name:
        raise ConfigError(
            f"episode {episode.episode_id} is on map {episode.map_name}, world is {world.map_name}"
        )
    if world is None:
        # Nothing to draw images from: the metadata must not claim what is not written.
        options = replace(options, observations=False, map_tile_max_side_px=0)
    writer.add_metadata(t.EPISODE_METADATA, episode_metadata(episode, options))
    georef = episode.georef
    views = episode.gt_path_corners
    poses = [view_to_pose(corners, georef) for corners in views]
    write_static_content(episode, world, poses, writer, options)
    dialog = _dialog_by_view(episode)
    centres = view_centre(views)
    turn_index = 0
    for k, (p, corners) in enumerate(zip(poses, views, strict=True)):
        t_ns = k * CLOCK_STEP_NS
        drone = fx.frame_transform(
            t_ns,
            t.MAP_FRAME,
            t.DRONE_FRAME,
            fx.vector3(p.x_m, p.y_m, p.z_m),
            fx.yaw_quaternion(p.yaw_rad),
        )
        writer.write(t.TOPIC_TF, t.FRAME_TRANSFORM, drone, t_ns)
        lat, lng = centres[k]
        gps = fx.location_fix(t_ns, t.DRONE_FRAME, lat, lng, p.z_m)
        writer.write(t.TOPIC_GPS, t.LOCATION_FIX, gps, t_ns)
        if world is not None and options.observations:
            image = observe_view(world.bgr, corners, georef)
            data = encode_image(image, options.image_format, options.jpeg_quality)
            msg = fx.compressed_image_json(t_ns, t.CAMERA_FRAME, data, options.image_format)
            writer.write(t.TOPIC_GT_OBSERVATION, t.COMPRESSED_IMAGE, msg, t_ns)
        for turn in dialog.get(k, []):
            write_dialog_turn(writer, episode.episode_id, turn, turn_index, t_ns)
            turn_index += 1


def write_dialog_turn(
    writer: McapLogWriter, episode_id: str, turn: DialogTurn, index: int, t_ns: int
) -> None:
    message = {
        "timestamp": fx.timestamp(t_ns),
        "episode_id": episode_id,
        "round_index": turn.round_index,
        "turn_index": index,
        "speaker": turn.speaker,
        "text": turn.text,
    }
    writer.write(t.TOPIC_DIALOG, t.DIALOG_TURN, message, t_ns)
    text = f"[round {turn.round_index}] {turn.text}"
    writer.write(t.TOPIC_DIALOG_LOG, t.LOG, fx.log(t_ns, turn.speaker, text), t_ns)
