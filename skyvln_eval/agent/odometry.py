"""What an agent knows of its own flight: pose summary, the path flown since the
instruction it follows was given, and the roads below it there.

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
    """Where the instruction being followed was given (its start pose and the roads seen
    there), the last pose and the metres flown since: an instruction's distances and clock
    directions are said from there. An agent starts a new one when the commander answers
    mid-episode (a new round: its words are said from where the drone is then)."""

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
        """Where the instruction's start is from the drone now, and how far it has flown
        since (for prompts)."""
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
            f"Flown {self.travelled_m:.0f} m since the current instruction was given; where "
            f"it was given is {start:.0f} m away at bearing {bearing:.0f} deg (you faced "
            f"{data['start_heading_deg']:.0f} deg there)."
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
    """The roads seen below the drone now (and where the current instruction was given, if
    remembered), for prompts."""

    def show(bearings: Sequence[float]) -> str:
        return ", ".join(f"{b:.0f}" for b in bearings) or "none seen"

    text = f"Roads leaving from below you (compass deg): {show(here)}"
    if at_start is None:
        return text + "."
    return text + f"; where the current instruction was given: {show(at_start)}."
