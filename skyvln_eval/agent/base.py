"""The agent interface: ``reset(brief)`` once, then ``act(observation) -> Decision``.

The harness owns the world, the cameras and the episode's ground truth (as in Gymnasium,
the environment hands out observations). An agent is given an :class:`EpisodeBrief` (the
dialog so far, where it starts, the map's georeference, its step budget: nothing about the
goal or the route) and, at each step, an :class:`Observation`: its pose and view, the
feedback on its last action, new dialog turns, and a :class:`~skyvln_eval.sensing.Sensors`
handle through which it can turn in place and capture images, and nothing else.
"""

from __future__ import annotations

import zlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.actions import Action
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.avdn.records import DialogTurn
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.sensing import Sensors

if TYPE_CHECKING:
    from skyvln_eval.llm.client import LLMClient
    from skyvln_eval.llm.config import LLMConfig


@dataclass(frozen=True)
class EpisodeBrief:
    """What an agent knows when an episode starts.

    ``episode_key`` tells episodes apart, to seed an agent's randomness (:func:`episode_key`);
    the episode's id and map name are not given, since they are the keys of its
    annotations (the route and the goal). The key is a function of the id, so whoever
    holds the dataset can find the episode from it, as from the dialog: it is for seeding
    only, a rule (like the sensor handle's), not a wall. ``dialog`` is every turn so far
    (earlier rounds and the current round's question and instruction); ``current_round``
    the round the agent now follows. ``start_pose`` and ``start_view`` are where it starts
    (the view's ``[lat, lng]`` corners), ``georef`` the map's georeference, ``max_steps``
    the view budget, start included.
    """

    episode_key: int
    dialog: tuple[DialogTurn, ...]
    current_round: int
    start_pose: ViewPose
    start_view: NDArray[np.float64] = field(repr=False)
    georef: MapGeoref = field(repr=False)
    max_steps: int

    @property
    def instruction(self) -> str:
        """The commander's words of the current round."""
        return " ".join(
            t.text
            for t in self.dialog
            if t.round_index >= self.current_round and t.speaker == "commander"
        )


def episode_key(episode_id: str) -> int:
    """The :attr:`EpisodeBrief.episode_key` of an episode: its id's CRC-32 (stable across
    processes, unlike ``hash``)."""
    return zlib.crc32(episode_id.encode("utf-8"))


def episode_seed(seed: int, episode_key: int) -> int:
    """An agent's seed for one episode, from its own seed and the episode's key
    (:attr:`EpisodeBrief.episode_key`)."""
    return (seed * 1_000_003 + episode_key) % (2**32)


@dataclass(frozen=True, eq=False)
class Observation:
    """What the agent gets at one step.

    ``step_index`` counts views so far (0 at the start view); ``max_steps`` is the view
    budget, start included, so ``actions_left = max_steps - 1 - step_index``.
    ``feedback`` says what became of the previous action (e.g. a step the map border
    cancelled); ``new_dialog`` holds turns added since the last step (the commander's
    answer to the agent's question).
    """

    step_index: int
    max_steps: int
    pose: ViewPose
    view_corners: NDArray[np.float64]
    sensors: Sensors
    feedback: str | None = None
    new_dialog: tuple[DialogTurn, ...] = ()

    @property
    def actions_left(self) -> int:
        return max(0, self.max_steps - 1 - self.step_index)


@dataclass(frozen=True)
class Decision:
    """The agent's thought, its action, a JSON-able trace of how it got there, its LLM
    calls, the modules whose answers it could not use (``failures``; a failure of the
    action module means ``action`` is the safe fallback), and a question for the
    commander (``question``), which the harness may have answered by the next step."""

    thought: str
    action: Action
    trace: dict[str, Any] = field(default_factory=dict)
    llm_calls: tuple[LlmCall, ...] = ()
    failures: tuple[ModuleFailure, ...] = ()
    question: str | None = None


class Agent(ABC):
    """One small interface for every agent; ``settings`` is logged with every run."""

    name: str = "agent"

    def reset(self, brief: EpisodeBrief) -> None:  # noqa: B027 - optional hook
        """Start an episode."""

    @abstractmethod
    def act(self, observation: Observation) -> Decision:
        """The next action."""

    def settings(self) -> dict[str, Any]:
        return {"name": self.name}

    def llm_clients(self) -> tuple[LLMClient, ...]:
        """The LLM clients the agent calls through (its detector's too), whose records of
        the calls made count an episode's calls when a decision raised before handing
        them on; none for an agent that calls no LLM."""
        return ()


def llm_agent_settings(
    name: str, seed: int, client: LLMClient, llm: LLMConfig, perception: Any, **extra: Any
) -> dict[str, Any]:
    """The settings an LLM-driven agent records in every run."""
    return {
        "name": name,
        **extra,
        "seed": seed,
        "backend": client.backend.label,
        "llm": llm.model_dump(),
        "perception": perception.settings(),
    }
