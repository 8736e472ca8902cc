"""Entity paths and timelines of an episode recording, and the map-pixel frame.

One recording per episode. Two timelines: ``decision`` (the agent's decision index: a
message belongs to the last decision made at or before its time) and ``sim_time`` (the
run's simulated clock, seconds). Static content (map, ground truth) is timeless.

- ``map/...``: the 2-D map in map pixels (the official width-resized map image: x east,
  y south, :meth:`MapGeoref.gps_to_pixel_float`); the tile stored in the log is smaller and
  is scaled up onto these pixels;
- ``world/...``: the 3-D scene in ENU metres (x east, y north, z up);
- ``camera/...``: the official view below the drone at each decision, and every image the
  agent's camera captured, by view, with its detections;
- ``dialog``, ``agent/...``, ``llm/...``: text; ``control/...``: scalar signals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.frames import enu_to_latlng

APPLICATION_ID: Final = "skyvln-eval"
DECISION_TIMELINE: Final = "decision"
SIM_TIMELINE: Final = "sim_time"

MAP: Final = "map"
MAP_TILE: Final = "map/tile"
MAP_GT_ROUTE: Final = "map/gt_route"
MAP_GT_VIEWS: Final = "map/gt_views"
MAP_GOAL: Final = "map/goal"
MAP_ATTENTION: Final = "map/attention"
MAP_START: Final = "map/start"
MAP_PATH: Final = "map/flown_path"
MAP_DRONE: Final = "map/drone"
MAP_VIEWS: Final = "map/views"  # one child per decision: map/views/<k>
MAP_FINAL_VIEW: Final = "map/final_view"

WORLD: Final = "world"
WORLD_MAP: Final = "world/map"
WORLD_DRONE: Final = "world/drone"  # the level heading frame (position and yaw)
WORLD_DRONE_BODY: Final = "world/drone/body"  # the airframe's box, tilted in flown runs
WORLD_TRAJECTORY: Final = "world/trajectory"
WORLD_GT_ROUTE: Final = "world/gt_route"
WORLD_GOAL: Final = "world/goal"
WORLD_VIEWS: Final = "world/views"
WORLD_OBSTACLES: Final = "world/obstacles"
WORLD_TARGET: Final = "world/target"
WORLD_REFERENCE: Final = "world/reference"
WORLD_HORIZON: Final = "world/horizon"

CAMERA: Final = "camera"
CAMERA_OBSERVATION: Final = "camera/observation"
CAMERA_DETECTIONS: Final = "camera/detections"  # one child per view: image, boxes, sectors
#: The official view below each ground-truth view (episode logs, from `convert`).
CAMERA_GT_OBSERVATION: Final = "camera/gt_observation"


def camera_view(view: str) -> str:
    """The entity of one camera view the agent captured (its image under ``image``, the
    detections on it, the HSD sector grid under ``sectors``)."""
    return f"{CAMERA_DETECTIONS}/{view.replace(' ', '_').replace('+', '')}"


DIALOG: Final = "dialog"
AGENT_LOG: Final = "agent/log"
AGENT_STEP: Final = "agent/step"
AGENT_HSD: Final = "agent/hsd"
AGENT_MEMORY: Final = "agent/memory"
LLM_LOG: Final = "llm/log"
LLM: Final = "llm"  # one child per agent module: llm/<module>
CONTROL: Final = "control"
EPISODE_INFO: Final = "episode"


@dataclass(frozen=True)
class MapFrame:
    """ENU metres to map pixels for one map (the official pixel grid of the resized map)."""

    georef: MapGeoref

    def pixels(self, xy_m: ArrayLike) -> NDArray[np.float64]:
        """ENU ``[x_m, y_m]`` points (any leading shape) to map pixels ``[x, y]``."""
        xy = np.asarray(xy_m, dtype=np.float64)[..., :2]
        return self.georef.gps_to_pixel_float(enu_to_latlng(xy, self.georef))

    @property
    def size_px(self) -> tuple[float, float]:
        """Width and height of the whole map, in map pixels."""
        (lat0, lng0), (lat1, lng1) = self.georef.gps_botm_left, self.georef.gps_top_right
        return (lng1 - lng0) / self.georef.lat_ratio, (lat1 - lat0) / self.georef.lat_ratio
