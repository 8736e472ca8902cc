"""The agent interface: ``reset(episode, world)`` once, then ``act(observation) -> Decision``.

An agent sees the world only through the observation's camera rig (it may turn in place
and capture as often as it likes) and reads only the episode's dialog and start; the
ground-truth replay baseline is the one agent that reads the ground truth, by design.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.actions import Action
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.avdn.records import Episode
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.sim.camera import CameraRig
from skyvln_eval.worlds.tile import WorldTile


@dataclass(frozen=True, eq=False)
class Observation:
    """What the agent gets at one step.

    ``step_index`` counts views so far (0 at the start view); ``max_steps`` is the view
    budget, start included, so ``actions_left = max_steps - 1 - step_index``.
    ``feedback`` says what became of the previous action (e.g. a step the map border
    cancelled).
    """

    step_index: int
    max_steps: int
    pose: ViewPose
    view_corners: NDArray[np.float64]
    georef: MapGeoref
    camera: CameraRig
    feedback: str | None = None

    @property
    def actions_left(self) -> int:
        return max(0, self.max_steps - 1 - self.step_index)


@dataclass(frozen=True)
class Decision:
    """The agent's thought, its action, a JSON-able trace of how it got there, its LLM
    calls, and the modules whose answers it could not use (``failures``; a failure of the
    action module means ``action`` is the safe fallback)."""

    thought: str
    action: Action
    trace: dict[str, Any] = field(default_factory=dict)
    llm_calls: tuple[LlmCall, ...] = ()
    failures: tuple[ModuleFailure, ...] = ()

    @property
    def fallback_action(self) -> bool:
        return any(f.action_fallback for f in self.failures)


class Agent(ABC):
    """One small interface for every agent; ``settings`` is logged with every run."""

    name: str = "agent"

    def reset(self, episode: Episode, world: WorldTile) -> None:  # noqa: B027 - optional hook
        """Start an episode."""

    @abstractmethod
    def act(self, observation: Observation) -> Decision:
        """The next action."""

    def settings(self) -> dict[str, Any]:
        return {"name": self.name}
