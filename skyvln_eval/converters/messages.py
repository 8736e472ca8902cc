"""Builders for Foxglove well-known messages in their JSON encoding.

Foxglove's JSON encoding writes times as ``{"sec", "nsec"}``, bytes fields as base64
strings, and enums as integers. Builders take SI units (metres, radians, nanoseconds) and
return plain dicts with Python floats, ready for :meth:`McapLogWriter.write`.
"""

from __future__ import annotations

import base64
import functools
import json
import math
from collections.abc import Iterable, Sequence
from typing import Any, Final

from skyvln_eval.converters.json_template import JsonTemplate, slot

Json = dict[str, Any]
Rgba = tuple[float, float, float, float]

NS_PER_S: Final = 1_000_000_000
#: foxglove.LineType
LINE_STRIP: Final = 0
LINE_LOOP: Final = 1
#: foxglove.Log level INFO.
LOG_INFO: Final = 2
#: foxglove.LocationFix position_covariance_type UNKNOWN.
COVARIANCE_UNKNOWN: Final = 0


def timestamp(t_ns: int) -> Json:
    """Foxglove time from integer nanoseconds."""
    sec, nsec = divmod(t_ns, NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def timestamp_slots() -> Json:
    """:func:`timestamp` as slots 0 (seconds) and 1 (nanoseconds) of a message template
    (:mod:`.json_template`): every template of the logs has the time first."""
    return {"sec": slot(0), "nsec": slot(1)}


def timestamp_texts(t_ns: int) -> tuple[str, str]:
    """The JSON texts that fill :func:`timestamp_slots` for ``t_ns``."""
    sec, nsec = divmod(t_ns, NS_PER_S)
    return str(sec), str(nsec)


def vector3(x: float, y: float, z: float) -> Json:
    return {"x": float(x), "y": float(y), "z": float(z)}


def yaw_quaternion(yaw_rad: float) -> Json:
    """Rotation about +z by ``yaw_rad`` (ENU yaw: 0 = east, counter-clockwise)."""
    half = 0.5 * float(yaw_rad)
    return {"x": 0.0, "y": 0.0, "z": math.sin(half), "w": math.cos(half)}


def attitude_quaternion(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Json:
    """The airframe's orientation in the map: yaw about +z, then the quadrotor model's
    world-frame roll about x (east) and pitch about y (north), ``Ry(pitch) Rx(roll)
    Rz(yaw)``, so the thrust axis is the model's ``Ry(pitch) Rx(roll) e_z``."""
    sr, cr = math.sin(0.5 * roll_rad), math.cos(0.5 * roll_rad)
    sp, cp = math.sin(0.5 * pitch_rad), math.cos(0.5 * pitch_rad)
    sy, cy = math.sin(0.5 * yaw_rad), math.cos(0.5 * yaw_rad)
    # (cp + sp j)(cr + sr i) = cp cr + cp sr i + sp cr j - sp sr k, then times (cy + sy k).
    w, x, y, z = cp * cr, cp * sr, sp * cr, -sp * sr
    return {
        "x": x * cy + y * sy,
        "y": y * cy - x * sy,
        "z": z * cy + w * sy,
        "w": w * cy - z * sy,
    }


#: The drone's heading frame (x forward, y left, z up) to the downward camera's optical
#: frame (x right, y down in the image = backwards, z into the scene = down): a half turn
#: about (1, -1, 0) / sqrt 2.
CAMERA_FROM_DRONE_QUATERNION: Final[Json] = {
    "x": math.sqrt(0.5),
    "y": -math.sqrt(0.5),
    "z": 0.0,
    "w": 0.0,
}
IDENTITY_QUATERNION: Final[Json] = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def optical_frame_quaternion(
    forward: Sequence[float], right: Sequence[float], up: Sequence[float]
) -> Json:
    """The orientation of a camera's optical frame (x right, y down in the image, z along
    the optical axis: Foxglove's and ROS's) whose image axes are the orthonormal
    ``forward``, ``right`` and ``up`` of its parent frame.

    The rotation's columns are the optical axes in the parent: ``right``, ``-up``,
    ``forward``; its quaternion is read from the largest of its four diagonal terms
    (Shepperd's method), so it is exact to rounding in every orientation.
    """
    m = [[float(right[i]), -float(up[i]), float(forward[i])] for i in range(3)]
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    # (w, x, y, z) times 4 q_k, for each k: the one whose own term (4 q_k^2) is largest.
    candidates = (
        (1.0 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01),
        (m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20),
        (m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21),
        (m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22),
    )
    k = max(range(4), key=lambda k: candidates[k][k])
    norm = math.sqrt(sum(c * c for c in candidates[k]))
    w, x, y, z = (c / norm for c in candidates[k])
    return {"x": x, "y": y, "z": z, "w": w}


def pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> Json:
    return {"position": vector3(x_m, y_m, z_m), "orientation": yaw_quaternion(yaw_rad)}


def pose_in_frame(t_ns: int, frame_id: str, pose_json: Json) -> Json:
    return {"timestamp": timestamp(t_ns), "frame_id": frame_id, "pose": pose_json}


def poses_in_frame(t_ns: int, frame_id: str, poses: Sequence[Json]) -> Json:
    return {"timestamp": timestamp(t_ns), "frame_id": frame_id, "poses": list(poses)}


def frame_transform(t_ns: int, parent: str, child: str, translation: Json, rotation: Json) -> Json:
    return {
        "timestamp": timestamp(t_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": translation,
        "rotation": rotation,
    }


def color(rgba: Rgba) -> Json:
    r, g, b, a = rgba
    return {"r": float(r), "g": float(g), "b": float(b), "a": float(a)}


def line(points_xyz: Iterable[Sequence[float]], rgba: Rgba, loop: bool, width_px: float) -> Json:
    """A line primitive with ``width_px`` screen pixels (scale invariant) in its entity frame."""
    return {
        "type": LINE_LOOP if loop else LINE_STRIP,
        "pose": {"position": vector3(0.0, 0.0, 0.0), "orientation": IDENTITY_QUATERNION},
        "thickness": float(width_px),
        "scale_invariant": True,
        "points": [vector3(*p) for p in points_xyz],
        "color": color(rgba),
        "colors": [],
        "indices": [],
    }


def sphere(centre_xyz: Sequence[float], diameter_m: float, rgba: Rgba) -> Json:
    """A sphere primitive of ``diameter_m`` centred at ``centre_xyz`` in its entity frame."""
    return {
        "pose": {"position": vector3(*centre_xyz), "orientation": IDENTITY_QUATERNION},
        "size": vector3(diameter_m, diameter_m, diameter_m),
        "color": color(rgba),
    }


def scene_update(
    t_ns: int,
    frame_id: str,
    entity_id: str,
    lines: Sequence[Json],
    metadata: dict[str, str],
    spheres: Sequence[Json] = (),
) -> Json:
    """One entity of line (and sphere) primitives, shown forever (lifetime 0) until replaced."""
    entity = {
        "timestamp": timestamp(t_ns),
        "frame_id": frame_id,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": k, "value": v} for k, v in metadata.items()],
        "arrows": [],
        "cubes": [],
        "spheres": list(spheres),
        "cylinders": [],
        "lines": list(lines),
        "triangles": [],
        "texts": [],
        "models": [],
    }
    return {"deletions": [], "entities": [entity]}


def compressed_image(t_ns: int, frame_id: str, data: bytes, image_format: str) -> Json:
    return {
        "timestamp": timestamp(t_ns),
        "frame_id": frame_id,
        "data": base64.b64encode(data).decode("ascii"),
        "format": image_format,
    }


@functools.cache
def _compressed_image_template() -> JsonTemplate:
    message = compressed_image(0, slot(2), b"", slot(4))
    message["timestamp"] = timestamp_slots()
    message["data"] = slot(3)
    return JsonTemplate(message)


def compressed_image_json(t_ns: int, frame_id: str, data: bytes, image_format: str) -> bytes:
    """:func:`compressed_image` as the log writer encodes it, without the dict: images are
    most of a log's bytes, and the encoder scans every character of their base64 text
    (which needs no escaping) for characters to escape."""
    return _compressed_image_template().fill(
        *timestamp_texts(t_ns),
        json.dumps(frame_id, ensure_ascii=False),
        f'"{base64.b64encode(data).decode("ascii")}"',
        json.dumps(image_format, ensure_ascii=False),
    )


def location_fix(
    t_ns: int, frame_id: str, latitude: float, longitude: float, altitude_m: float
) -> Json:
    return {
        "timestamp": timestamp(t_ns),
        "frame_id": frame_id,
        "latitude": float(latitude),
        "longitude": float(longitude),
        "altitude": float(altitude_m),
        "position_covariance": [0.0] * 9,
        "position_covariance_type": COVARIANCE_UNKNOWN,
    }


def log(t_ns: int, name: str, message: str) -> Json:
    return {
        "timestamp": timestamp(t_ns),
        "level": LOG_INFO,
        "message": message,
        "name": name,
        "file": "",
        "line": 0,
    }
