"""Multimodal perception: a panorama by turning in place, detection, localisation, merging.

Each step the drone turns through ``headings`` evenly spaced headings with the camera
pitched down ``pitch_deg`` (plus, by default, one straight-down view: the area of the
current AVDN view) through the drone's sensors (images only). Every detection is placed
on the ground from the depth image (median of its pixels' 3-D points; without a depth
sensor, where its pixels' rays meet flat ground), giving its distance, compass bearing
and size. A landmark
seen in several views keeps the view where its score is highest (as in the paper);
sightings are matched to earlier steps' by label and position, so a landmark keeps its id
(``L1``, ``L2``, ...) for the whole episode.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import Field

from skyvln_eval.agent.detectors import Box, Detection, Detector
from skyvln_eval.agent.order_stats import column_median_and_percentiles
from skyvln_eval.config_model import StrictModel
from skyvln_eval.frames import ViewPose, enu_yaw_to_compass_deg
from skyvln_eval.sensing import CameraImages, Sensors

_FOUR_VIEWS = ("front", "right", "back", "left")


class PerceptionConfig(StrictModel):
    """How the agent looks around (angles in degrees, distances in metres)."""

    headings: int = Field(default=4, ge=1, le=16, description="panorama headings, evenly spaced")
    pitch_deg: float = Field(
        default=60.0, ge=0.0, le=90.0, description="camera pitch down for the panorama"
    )
    include_below: bool = Field(default=True, description="also look straight down (the AVDN view)")
    merge_radius_m: float = Field(default=20.0, gt=0.0, description="same landmark across views")
    track_radius_m: float = Field(default=25.0, gt=0.0, description="same landmark across steps")


@dataclass(frozen=True, eq=False)
class CapturedView:
    """One view of the panorama: its name, compass heading, pitch, and the images."""

    index: int
    name: str
    heading_deg: float
    pitch_deg: float
    images: CameraImages


@dataclass(frozen=True)
class Sighting:
    """A landmark as perceived this step, in its best view.

    ``east_m`` / ``north_m`` is its displacement from the drone, ``x_m`` / ``y_m`` its
    ENU position, ``distance_m`` horizontal, ``bearing_deg`` the compass bearing from the
    drone, ``size_m`` its estimated extent on the ground (the largest over the views that
    saw it), ``clipped`` whether every view saw it cut by the image border (so it may be
    larger than ``size_m``).
    """

    landmark_id: str
    label: str
    caption: str
    score: float
    view_index: int
    view_name: str
    view_heading_deg: float
    box_px: Box
    image_size_px: tuple[int, int]
    x_m: float
    y_m: float
    east_m: float
    north_m: float
    distance_m: float
    bearing_deg: float
    size_m: float
    clipped: bool = False


@dataclass(frozen=True, eq=False)
class Panorama:
    """The views of one step, the landmarks in them, and the roads leaving from below.

    ``road_bearings_deg`` are compass bearings of roads leaving the point below the drone,
    as the detector reads them from the straight-down view (empty if it cannot).
    """

    views: tuple[CapturedView, ...]
    sightings: tuple[Sighting, ...]
    road_bearings_deg: tuple[float, ...] = ()

    def by_id(self) -> dict[str, Sighting]:
        return {s.landmark_id: s for s in self.sightings}

    def view_records(self) -> list[dict[str, Any]]:
        """The views by name, heading and pitch, for a decision's trace (the run log names
        the captured images after them)."""
        return [
            {"name": v.name, "heading_deg": v.heading_deg, "pitch_deg": v.pitch_deg}
            for v in self.views
        ]


@dataclass
class LandmarkTracker:
    """Gives a landmark the same id whenever it is seen again (same label, nearby).

    "Nearby" grows with the landmark's size: the estimated centre of a large landmark
    moves as different parts of it come into view.
    """

    radius_m: float
    tracks: list[tuple[str, str, float, float, float]] = field(default_factory=list)

    def assign(self, label: str, x_m: float, y_m: float, size_m: float, taken: set[str]) -> str:
        """The id of the nearest track with this label, or a new one; ``taken`` ids are skipped."""
        best: tuple[float, int] | None = None
        for i, (track_id, track_label, tx, ty, tsize) in enumerate(self.tracks):
            d = math.hypot(tx - x_m, ty - y_m)
            reach = max(self.radius_m, 0.5 * max(size_m, tsize))
            close = track_label == label and d <= reach and track_id not in taken
            if close and (best is None or d < best[0]):
                best = (d, i)
        if best is None:
            landmark_id = f"L{len(self.tracks) + 1}"
            self.tracks.append((landmark_id, label, x_m, y_m, size_m))
            return landmark_id
        landmark_id = self.tracks[best[1]][0]
        self.tracks[best[1]] = (landmark_id, label, x_m, y_m, max(size_m, self.tracks[best[1]][4]))
        return landmark_id


@dataclass
class _Found:
    """A detection placed on the ground; ``clipped`` when it touches its image's border."""

    detection: Detection
    view: CapturedView
    x_m: float
    y_m: float
    size_m: float
    clipped: bool


def view_name(index: int, count: int) -> str:
    if count == 4:
        return _FOUR_VIEWS[index]
    return f"heading +{round(index * 360.0 / count)}"


def _localise(view: CapturedView, detection: Detection) -> _Found | None:
    """Ground position and extent (m) of a detection, from its pixels' depth."""
    images = view.images
    x0, y0, x1, y1 = detection.box_px
    width, height = images.size_px
    # Only the box's pixels can count: work in its window, not on whole-image masks.
    window = (slice(max(y0, 0), max(y1, 0)), slice(max(x0, 0), max(x1, 0)))
    region = images.finite_depth()[window].copy()
    if detection.mask is not None:
        region &= detection.mask[window]
    v, u = np.nonzero(region)
    if len(u) == 0:
        return None
    v, u = v + window[0].start, u + window[1].start
    points = images.points_enu(u, v)[:, :2]
    (x, y), (low, high) = column_median_and_percentiles(points, (5, 95))
    clipped = bool(u.min() == 0 or v.min() == 0 or u.max() == width - 1 or v.max() == height - 1)
    return _Found(detection, view, float(x), float(y), float(np.max(high - low)), clipped)


def merge_views(found: Sequence[_Found], radius_m: float) -> list[_Found]:
    """One entry per landmark: the view with the best score, the largest size seen."""
    kept: list[_Found] = []
    for item in sorted(found, key=lambda f: -f.detection.score):
        for k in kept:
            reach = max(radius_m, 0.5 * max(k.size_m, item.size_m))
            same = k.detection.label == item.detection.label
            if same and math.hypot(k.x_m - item.x_m, k.y_m - item.y_m) <= reach:
                k.size_m = max(k.size_m, item.size_m)
                k.clipped = k.clipped and item.clipped
                break
        else:
            kept.append(item)
    return kept


class Perception:
    """Panorama, detection and localisation for one agent (see the module docstring)."""

    def __init__(self, config: PerceptionConfig, detector: Detector) -> None:
        self.config = config
        self.detector = detector
        self.tracker = LandmarkTracker(config.track_radius_m)

    def reset(self, seed: int) -> None:
        self.detector.reset(seed)
        self.tracker = LandmarkTracker(self.config.track_radius_m)

    def capture(self, sensors: Sensors, pose: ViewPose) -> list[CapturedView]:
        """The panorama's views (and the one straight down), captured as one batch."""
        n = self.config.headings
        wanted = [
            ((pose.heading_deg + k * 360.0 / n) % 360.0, self.config.pitch_deg) for k in range(n)
        ]
        if self.config.include_below:
            wanted.append((pose.heading_deg, 90.0))
        images = sensors.capture_many(wanted)
        names = [view_name(k, n) for k in range(n)] + ["below"]
        return [
            CapturedView(k, names[k], heading, pitch, image)
            for k, ((heading, pitch), image) in enumerate(zip(wanted, images, strict=True))
        ]

    def observe(self, sensors: Sensors, pose: ViewPose, phrases: Sequence[str] = ()) -> Panorama:
        """Look around from ``pose`` and return every landmark found, once each."""
        views = self.capture(sensors, pose)
        found = []
        for view in views:
            for detection in self.detector.detect(view.images, phrases):
                place = _localise(view, detection)
                if place is not None:
                    found.append(place)
        sightings: list[Sighting] = []
        taken: set[str] = set()
        for f in merge_views(found, self.config.merge_radius_m):
            east, north = f.x_m - pose.x_m, f.y_m - pose.y_m
            w, h = f.view.images.size_px
            landmark_id = self.tracker.assign(f.detection.label, f.x_m, f.y_m, f.size_m, taken)
            taken.add(landmark_id)
            sightings.append(
                Sighting(
                    landmark_id=landmark_id,
                    label=f.detection.label,
                    caption=f.detection.caption,
                    score=round(f.detection.score, 3),
                    view_index=f.view.index,
                    view_name=f.view.name,
                    view_heading_deg=round(f.view.heading_deg, 1),
                    box_px=f.detection.box_px,
                    image_size_px=(w, h),
                    x_m=f.x_m,
                    y_m=f.y_m,
                    east_m=east,
                    north_m=north,
                    distance_m=math.hypot(east, north),
                    bearing_deg=float(enu_yaw_to_compass_deg(math.atan2(north, east))),
                    size_m=f.size_m,
                    clipped=f.clipped,
                )
            )
        sightings.sort(key=lambda s: int(s.landmark_id[1:]))
        roads: tuple[float, ...] = ()
        if self.config.include_below:  # the detector reads the roads, if it can
            roads = self.detector.road_bearings(views[-1].images, pose.heading_deg)
        return Panorama(tuple(views), tuple(sightings), roads)

    def settings(self) -> dict[str, Any]:
        return {**self.config.model_dump(), "detector": self.detector.settings()}
