"""Geometry of a recording: the 2-D map (map pixels) and the 3-D scene (ENU metres).

Functions here turn the logged Foxglove messages (``PosesInFrame``, ``SceneUpdate``,
``FrameTransform``, ``PoseInFrame``) into plain arrays; :mod:`.recording` logs them.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

Json = Mapping[str, Any]
Rgba8 = tuple[int, int, int, int]

GT_RGBA: Rgba8 = (40, 200, 60, 255)
FLOWN_RGBA: Rgba8 = (30, 150, 255, 255)
FINAL_VIEW_RGBA: Rgba8 = (255, 60, 200, 255)
DRONE_RGBA: Rgba8 = (255, 255, 255, 255)
TARGET_RGBA: Rgba8 = (255, 220, 0, 255)
REFERENCE_RGBA: Rgba8 = (255, 140, 0, 255)
HORIZON_RGBA: Rgba8 = (255, 80, 80, 255)


def xyz(vector: Json) -> list[float]:
    return [float(vector.get("x", 0.0)), float(vector.get("y", 0.0)), float(vector.get("z", 0.0))]


def rgba8(colour: Json | None, default: Rgba8) -> Rgba8:
    if not colour:
        return default
    channels = [colour.get(k, 1.0) for k in ("r", "g", "b", "a")]
    r, g, b, a = (round(255 * min(1.0, max(0.0, float(c)))) for c in channels)
    return r, g, b, a


def quaternion_xyzw(rotation: Json) -> list[float]:
    return [float(rotation.get(k, 1.0 if k == "w" else 0.0)) for k in ("x", "y", "z", "w")]


def relative_rotation_xyzw(parent: Sequence[float], child: Sequence[float]) -> list[float]:
    """The rotation taking frame ``parent`` to ``child`` (both given in one frame, as
    x, y, z, w): ``conj(parent) * child``."""
    px, py, pz, pw = (-parent[0], -parent[1], -parent[2], parent[3])
    cx, cy, cz, cw = child
    return [
        pw * cx + px * cw + py * cz - pz * cy,
        pw * cy - px * cz + py * cw + pz * cx,
        pw * cz + px * cy - py * cx + pz * cw,
        pw * cw - px * cx - py * cy - pz * cz,
    ]


def pose_positions(message: Json) -> NDArray[np.float64]:
    """Positions (n x 3, metres) of a ``PosesInFrame``."""
    points = [xyz(p.get("position", {})) for p in message.get("poses", [])]
    return np.asarray(points, dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True)
class Strip:
    """One line primitive of a ``SceneUpdate``: its points (n x 3, metres) and colour."""

    points: NDArray[np.float64]
    rgba: Rgba8
    loop: bool


def scene_strips(message: Json, default: Rgba8 = GT_RGBA) -> list[Strip]:
    """Every line of every entity of a ``SceneUpdate`` (loops closed by repeating point 0)."""
    strips = []
    for entity in message.get("entities", []):
        for line in entity.get("lines", []):
            points = np.asarray([xyz(p) for p in line.get("points", [])], np.float64).reshape(-1, 3)
            loop = line.get("type") == 1  # foxglove.LineType LINE_LOOP
            if loop and len(points):
                points = np.vstack([points, points[:1]])
            strips.append(Strip(points, rgba8(line.get("color"), default), loop))
    return strips


@dataclass(frozen=True)
class Spheres:
    """Spheres of a ``SceneUpdate``: centres (n x 3, m), radii (n, m) and colours."""

    centres: NDArray[np.float64]
    radii_m: NDArray[np.float64]
    colours: list[Rgba8]


def scene_spheres(message: Json) -> Spheres:
    centres, radii, colours = [], [], []
    for entity in message.get("entities", []):
        for sphere in entity.get("spheres", []):
            centres.append(xyz(sphere.get("pose", {}).get("position", {})))
            size = sphere.get("size", {})
            radii.append(0.5 * float(size.get("x", 0.0)))
            colours.append(rgba8(sphere.get("color"), (255, 80, 30, 150)))
    return Spheres(np.asarray(centres, np.float64).reshape(-1, 3), np.asarray(radii), colours)


def image_bytes(message: Json) -> tuple[bytes, str]:
    """A ``CompressedImage``'s encoded bytes and media type (the bytes are not decoded)."""
    data = base64.b64decode(message.get("data", ""))
    image_format = str(message.get("format", "jpeg")).lower()
    return data, "image/png" if image_format == "png" else "image/jpeg"


def decode_rgb(data: bytes) -> NDArray[np.uint8] | None:
    """An encoded image as RGB pixels, or None if it cannot be decoded."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    # cvtColor, not a reversed-channel copy: the same pixels, several times faster.
    return None if image is None else np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))


@dataclass
class Flight:
    """The drone's positions so far (from ``/tf``), for the flown path and trajectory."""

    positions: list[list[float]] = field(default_factory=list)

    def add(self, position: Sequence[float]) -> None:
        self.positions.append([float(v) for v in position])

    def array(self) -> NDArray[np.float64]:
        return np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)


def sector_box(sector: int, width_px: float, height_px: float) -> list[float]:
    """The HSD sector cell (0-8, row-major from the upper left) as an XYXY pixel box."""
    row, col = divmod(int(sector), 3)
    return [
        col * width_px / 3,
        row * height_px / 3,
        (col + 1) * width_px / 3,
        (row + 1) * height_px / 3,
    ]


@dataclass(frozen=True)
class Detections:
    """Boxes of one panorama view at one decision: XYXY pixels, labels, and their source."""

    boxes: list[list[float]]
    labels: list[str]


def detections_by_view(
    sightings: Sequence[Json], default_size_px: tuple[int, int]
) -> dict[str, Detections]:
    """Group a decision's sightings by view: the logged box, else its HSD sector cell."""
    out: dict[str, Detections] = {}
    for entry in sightings:
        view = str(entry.get("view", "unknown"))
        width, height = entry.get("image_size_px") or default_size_px
        label = f"{entry.get('id', '?')} {entry.get('label', '?')}"
        if entry.get("score") is not None:
            label += f" {float(entry['score']):.2f}"
        if entry.get("box_px") is not None:
            box = [float(v) for v in entry["box_px"]]
        elif entry.get("sector") is not None:
            box = sector_box(int(entry["sector"]), float(width), float(height))
            label += f" (sector #{entry['sector']})"
        else:
            continue
        found = out.setdefault(view, Detections([], []))
        found.boxes.append(box)
        found.labels.append(label)
    return out


def frame_and_grid(width_px: float, height_px: float) -> list[list[list[float]]]:
    """The outline of a view image and its 3 x 3 HSD sector grid, as 2-D strips."""
    w, h = float(width_px), float(height_px)
    strips = [[[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [0.0, 0.0]]]
    for k in (1, 2):
        strips.append([[k * w / 3, 0.0], [k * w / 3, h]])
        strips.append([[0.0, k * h / 3], [w, k * h / 3]])
    return strips
