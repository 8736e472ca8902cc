"""The ground-truth replay oracle: built by the harness from the episode, never an agent.

No agent may read the route. The replay is a baseline that does, on purpose, to bound
what the official step and the metrics allow: at each step the AVDN waypoint from its
current view to the next ground-truth view, then STOP. The harness builds it explicitly
from the episode (:func:`ground_truth_oracle`) and its settings say it is an oracle, as
does every result row it leaves (``extra["oracle"]``, :func:`is_oracle`), so that a table
made from the scores alone never ranks it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.actions import Stop, Waypoint
from skyvln_eval.agent.base import Agent, Decision, EpisodeBrief, Observation
from skyvln_eval.avdn.records import Episode
from skyvln_eval.avdn.step import action_between_views


class GroundTruthOracle(Agent):
    """Replays a ground-truth route (an oracle; see the module docstring)."""

    name = "ground_truth"

    def __init__(self, gt_path_corners: NDArray[np.float64]) -> None:
        gt = np.asarray(gt_path_corners, dtype=np.float64)
        # ANDH-Full repeats each round's start view (the previous round's end): skip repeats.
        keep = [0] + [
            k for k in range(1, len(gt)) if not np.allclose(gt[k], gt[k - 1], rtol=0.0, atol=1e-9)
        ]
        self._targets = gt[keep][1:]
        self._next = 0

    def settings(self) -> dict[str, Any]:
        return {"name": self.name, "oracle": True, "reads": "the ground-truth route"}

    def reset(self, brief: EpisodeBrief) -> None:
        self._next = 0

    def act(self, observation: Observation) -> Decision:
        if self._next >= len(self._targets):
            return Decision("at the end of the ground truth", Stop(), {"target_index": None})
        official = action_between_views(observation.view_corners, self._targets[self._next])
        self._next += 1
        action = Waypoint(official.waypoint[0], official.waypoint[1], official.altitude)
        return Decision(
            f"towards ground-truth view {self._next}", action, {"target_index": self._next}
        )


def is_oracle(agent_name: str) -> bool:
    """Whether a run of the agent ``agent_name`` is flown by the harness's oracle."""
    return agent_name == GroundTruthOracle.name


def ground_truth_oracle(episode: Episode) -> GroundTruthOracle:
    """The replay of ``episode``'s ground-truth route (the harness's, not an agent's)."""
    return GroundTruthOracle(episode.gt_path_corners)
