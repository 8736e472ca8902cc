"""How the SkyVLN agent notices it went wrong: the landmark it flew to is not there.

After a fly-to towards the landmark taken for a stop goal, the next look around should
show it below. If it does not (a detector's phantom, a landmark mistaken for another),
TrackBack memory rejects it, gives the way back to the place where the decision was made,
and the LLM formulates a clarification question for the commander (:mod:`.clarify`).
Without memory the agent cannot tell that anything went wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from skyvln_eval.agent.clarify import ask_commander
from skyvln_eval.agent.memory import TrackBackMemory, WayBack
from skyvln_eval.agent.perception import Panorama, Sighting
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm_records import LlmCall, ModuleFailure


@dataclass(frozen=True)
class Pursuit:
    """A fly-to towards ``landmark`` taken for ``phrase``, decided at memory node ``place``."""

    landmark: Sighting
    phrase: str
    place: str | None

    def arrived(self, pose: ViewPose) -> bool:
        """Close enough to judge (a long fly-to is cut to one view's reach)."""
        s = self.landmark
        return math.hypot(s.x_m - pose.x_m, s.y_m - pose.y_m) <= 0.3 * pose.edge_m

    def found_in(self, panorama: Panorama) -> bool:
        """Whether a landmark with the same label is seen where the pursued one was."""
        s = self.landmark
        reach = max(25.0, 0.5 * s.size_m)
        return any(
            o.label == s.label and math.hypot(o.x_m - s.x_m, o.y_m - s.y_m) <= reach
            for o in panorama.sightings
        )


@dataclass
class Verdict:
    """What the check found: a way back and a question when the agent went wrong."""

    way_back: WayBack | None = None
    question: str | None = None
    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    failures: list[ModuleFailure] = field(default_factory=list)


def check_pursuit(
    pursuit: Pursuit,
    panorama: Panorama,
    pose: ViewPose,
    memory: TrackBackMemory | None,
    client: LLMClient,
    llm: LLMConfig,
) -> Verdict:
    """Judge a finished fly-to (see the module docstring)."""
    if not pursuit.arrived(pose) or memory is None:
        return Verdict()  # not there yet, or no memory to tell right from wrong
    lid = pursuit.landmark.landmark_id
    if pursuit.found_in(panorama):
        memory.mark_goal(lid, pursuit.phrase)
        return Verdict()
    reason = f"{lid}, taken for {pursuit.phrase!r}, was not there when I arrived"
    memory.reject(lid, reason)
    if pursuit.place is None:
        return Verdict()
    way_back = memory.way_back(pursuit.place, pose, reason)
    asked = ask_commander(client, llm, reason, pursuit.phrase, memory.clue(pose))
    return Verdict(way_back, asked.question, asked.records, asked.exchanges, asked.failures)
