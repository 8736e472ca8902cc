"""What an agent knows of its own flight: pose summary, path flown, roads at the start.

Shared by the SkyVLN agent (where the path is TrackBack memory's to tell) and the
NavGPT-style baseline (where it is the history NavGPT keeps in its prompt).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from skyvln_eval.frames import ViewPose


@dataclass
class Odometer:
    """The start pose, the last pose, metres flown, and the roads seen at the start."""

    start: ViewPose | None = None
    previous: ViewPose | None = None
    travelled_m: float = 0.0
    start_roads: tuple[float, ...] | None = None

    def update(self, pose: ViewPose, roads_deg: Sequence[float]) -> None:
        """Record the pose (and the roads below it) of a new step."""
        if self.start is None:
            self.start = pose
            self.start_roads = tuple(roads_deg)
        if self.previous is not None:
            self.travelled_m += math.hypot(
                pose.x_m - self.previous.x_m, pose.y_m - self.previous.y_m
            )
        self.previous = pose

    def to_dict(self) -> dict[str, float]:
        """Where the start is from the drone now, and how far it has flown (for prompts)."""
        if self.start is None or self.previous is None:
            return {}
        return {
            "travelled_m": round(self.travelled_m, 1),
            "start_east_m": round(self.start.x_m - self.previous.x_m, 2),
            "start_north_m": round(self.start.y_m - self.previous.y_m, 2),
            "start_heading_deg": round(self.start.heading_deg, 1),
        }

    def text(self) -> str:
        data = self.to_dict()
        if not data:
            return "Nothing flown yet."
        east, north = data["start_east_m"], data["start_north_m"]
        start = math.hypot(east, north)
        bearing = math.degrees(math.atan2(east, north)) % 360.0
        return (
            f"Flown {self.travelled_m:.0f} m; the start is {start:.0f} m away at bearing "
            f"{bearing:.0f} deg (you faced {data['start_heading_deg']:.0f} deg there)."
        )


def pose_summary(pose: ViewPose) -> dict[str, float]:
    """Heading, height, view edge and one step's reach, for prompts."""
    return {
        "heading_deg": round(pose.heading_deg, 1),
        "height_m": round(pose.z_m, 1),
        "view_edge_m": round(pose.edge_m, 1),
        "max_forward_m": round(pose.edge_m / 2.0, 1),
    }


def roads_text(here: Sequence[float], at_start: Sequence[float] | None) -> str:
    """The roads seen below the drone now (and at the start, if remembered), for prompts."""

    def show(bearings: Sequence[float]) -> str:
        return ", ".join(f"{b:.0f}" for b in bearings) or "none seen"

    text = f"Roads leaving from below you (compass deg): {show(here)}"
    return text + ("." if at_start is None else f"; at the start: {show(at_start)}.")
