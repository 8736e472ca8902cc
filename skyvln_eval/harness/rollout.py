"""What an agent did in one episode, whichever the execution mode."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.actions import Action, Stop
from skyvln_eval.agent.base import Agent, Decision, EpisodeBrief, Observation, episode_key
from skyvln_eval.avdn.constants import DEFAULT_MAX_ACTION_LEN
from skyvln_eval.avdn.records import DialogTurn, Episode
from skyvln_eval.errors import CacheMissError, LLMAuthError, SkyvlnError
from skyvln_eval.frames import ViewPose, view_to_pose
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.sensing import SensorConfig
from skyvln_eval.sim.sensors import Capture, SimulatedSensors
from skyvln_eval.worlds.tile import WorldTile

if TYPE_CHECKING:
    from skyvln_eval.harness.commander import SimulatedCommander
    from skyvln_eval.llm.client import LLMClient


def _failures_at(trace: dict[str, Any], step: int) -> dict[str, Any]:
    """``trace`` with the module failures it lists numbered by the decision they are of,
    as the episode's row numbers them (an agent does not know its step: its trace said -1,
    the row 0, and the viewer showed the trace's)."""
    listed = trace.get("failures")
    if not isinstance(listed, list):
        return trace
    numbered = [{**f, "step_index": step} if isinstance(f, dict) else f for f in listed]
    return {**trace, "failures": numbered}


class CallsMade:
    """The LLM calls an agent's clients make from now on: how the calls of a decision that
    raised (and handed on no records) are still counted, and paid for."""

    def __init__(self, agent: Agent) -> None:
        clients: dict[int, LLMClient] = {}
        for client in agent.llm_clients():  # a detector may share the agent's client
            clients.setdefault(id(client), client)
        self._marks = [(client, len(client.calls_made())) for client in clients.values()]

    def since(self) -> list[LlmCall]:
        """The records of the calls made since this was made, client by client."""
        return [call for client, mark in self._marks for call in client.calls_made(mark)]


def sealed(view: NDArray[np.float64]) -> NDArray[np.float64]:
    """A read-only copy of ``view`` for the agent. A copy, because a slice keeps its whole
    array in ``.base`` (the start view is a row of the ground-truth route); read-only, so
    that what the agent does to it cannot change the views the harness records and scores.
    """
    copy = np.array(view, dtype=np.float64, copy=True)
    copy.flags.writeable = False
    return copy


def episode_brief(episode: Episode, max_steps: int) -> EpisodeBrief:
    """What the agent is told of ``episode``: the dialog so far, where it starts, the map's
    georeference and the step budget. Not the goal, the route or the world."""
    georef = episode.georef
    start = sealed(episode.start_view)
    return EpisodeBrief(
        episode_key=episode_key(episode.episode_id),
        dialog=tuple(episode.dialog()),
        current_round=episode.first.round_index,
        start_pose=view_to_pose(start, georef),
        start_view=start,
        georef=georef,
        max_steps=max_steps,
    )


def answer_pending(
    rollout: Rollout, commander: SimulatedCommander | None, view: NDArray[np.float64]
) -> tuple[DialogTurn, ...]:
    """The commander's answer to the question of the last decision, as new dialog turns
    for the next observation (none without a commander, a question, or budget left)."""
    if commander is None or not rollout.questions:
        return ()
    pending = rollout.questions[-1]
    if pending["step"] != len(rollout.actions) - 1 or pending["answer"] is not None:
        return ()
    turns = commander.answer(pending["step"], pending["question"], view)
    if turns:
        pending["answer"] = turns[-1].text
    return turns


@dataclass(eq=False)
class Rollout:
    """Views (start included) and headings, and per decision: action, thought, the feedback
    the agent was given, its trace and its LLM calls. ``stop_reason`` says how it ended:
    ``stop`` (the agent's STOP), ``max_steps`` (the view budget), ``error`` (an agent error
    the user can cause; ``error`` holds it) or, flown, ``collision``. ``questions`` are the
    agent's clarification questions, with the commander's answers where it gave one.
    """

    episode_id: str
    views: list[NDArray[np.float64]]
    headings_deg: list[int]
    max_steps: int = DEFAULT_MAX_ACTION_LEN  # views, the start included (AVDN's max_action_len)
    actions: list[Action] = field(default_factory=list)
    thoughts: list[str] = field(default_factory=list)
    feedbacks: list[str | None] = field(default_factory=list)
    traces: list[dict[str, Any]] = field(default_factory=list)
    llm_calls: list[LlmCall] = field(default_factory=list)
    failures: list[ModuleFailure] = field(default_factory=list)
    questions: list[dict[str, Any]] = field(default_factory=list)
    #: Per decision, the images the agent captured for it (for the run log).
    captures: list[list[Capture]] = field(default_factory=list)
    stop_reason: str = "max_steps"
    error: str | None = None

    @property
    def final_view(self) -> NDArray[np.float64]:
        return self.views[-1]

    def record(self, decision: Decision, feedback: str | None) -> None:
        """Keep one decision and the feedback that preceded it."""
        step = len(self.actions)
        self.failures += [replace(f, step_index=step) for f in decision.failures]
        self.thoughts.append(decision.thought)
        self.feedbacks.append(feedback)
        self.traces.append(_failures_at(decision.trace, step))
        self.llm_calls.extend(decision.llm_calls)
        self.actions.append(decision.action)

    def observe_and_decide(
        self,
        agent: Agent,
        world: WorldTile,
        pose: ViewPose,
        view: NDArray[np.float64],
        sensors: SensorConfig,
        commander: SimulatedCommander | None,
        feedback: str | None,
    ) -> Action | None:
        """Hand the agent its observation at ``pose`` (its sensors there, the feedback, the
        commander's answer to its last question) and :meth:`decide`."""
        here = SimulatedSensors(world, pose.x_m, pose.y_m, pose.z_m, sensors)
        observation = Observation(
            step_index=len(self.views) - 1,
            max_steps=self.max_steps,
            pose=pose,
            view_corners=sealed(view),
            sensors=here.handle(),  # valid while ``here`` lives: for this decision
            feedback=feedback,
            new_dialog=answer_pending(self, commander, view),
        )
        action = self.decide(agent, observation)
        if len(self.captures) < len(self.actions):  # a decision was kept: with its images
            self.captures.append(list(here.captures))
        return action

    def decide(self, agent: Agent, observation: Observation) -> Action | None:
        """Ask the agent, keep its decision, and return the action to carry out.

        ``None`` ends the episode: the agent said STOP, or raised an error the user can
        cause (kept in ``error``; any other exception propagates and fails the episode).
        Refused credentials and a replay's cache miss propagate: no episode can go on.
        The calls of a decision that raised count all the same (as made: see
        :meth:`~skyvln_eval.llm.client.LLMClient.calls_made`).
        """
        made = CallsMade(agent)
        try:
            decision = agent.act(observation)
        except (LLMAuthError, CacheMissError):
            raise
        except SkyvlnError as error:
            self.stop_reason, self.error = "error", f"{type(error).__name__}: {error}"
            self.llm_calls += made.since()
            return None
        self.record(decision, observation.feedback)
        if decision.question:
            self.questions.append(
                {"step": len(self.actions) - 1, "question": decision.question, "answer": None}
            )
        if isinstance(decision.action, Stop):
            self.stop_reason = "stop"
            return None
        return decision.action
