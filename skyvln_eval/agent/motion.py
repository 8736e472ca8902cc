"""The LLM motion generator: system, action and navigation prompts -> thought and one action.

* System prompt: the embodiment (a drone, its camera, what its views mean, how it is judged).
* Action prompt: the possible actions with their limits and the output format (the same
  text at every step), then feedback on the last action and the actions left.
* Navigation prompt: the commander's words (earlier rounds and the current instruction),
  the drone's pose (and how far one step reaches from its height), the spatial
  descriptor's text (HSD or coarse), TrackBack memory's clues, and the sub-goals with
  their progress. The same content goes with the request as task data for the offline
  stand-ins (:mod:`skyvln_eval.llm.taskdata`), never as a second copy in the text.

A decision's text starts with what stays the same through an episode (the actions, then
the commander's words) and ends with what changes at every step: servers that keep the
previous prompt's computed prefix (llama.cpp does; hosted prompt caches do once the
shared part is long enough, OpenAI's from 1,024 tokens) compute only the rest. The
order follows the paper's (system, action, navigation prompt) with the dialog moved ahead
of the feedback.

The answer must be ``{"thought": ..., "action": {...}}`` (see :mod:`.parsing`). An
unusable answer is sent back for repair (:mod:`.calls`); if no answer can be used, the
safe fallback action (STOP: hover and end the episode where it is) is taken and recorded
as the motion module's failure.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final

from skyvln_eval.agent.actions import (
    ACTION_TYPES,
    MAX_CLIMB_M,
    MAX_HEIGHT_M,
    MAX_MOVE_M,
    MIN_HEIGHT_M,
    Action,
    Stop,
    decision_json_schema,
)
from skyvln_eval.agent.calls import call_json
from skyvln_eval.agent.parsing import parse_decision
from skyvln_eval.agent.subgoals import DialogText
from skyvln_eval.frames import ViewPose
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import RepairPolicy
from skyvln_eval.llm.taskdata import task_message
from skyvln_eval.llm.types import GenerationConfig, ImagePart, Message
from skyvln_eval.llm_records import LlmCall, ModuleFailure

SYSTEM_PROMPT: Final = (
    "You are the pilot of a quadrotor drone flying over a city, following a commander's "
    "instructions to a destination. Your front camera has a 90 degree field of view and is "
    "pitched down; it cannot turn sideways, so you turn the drone to look around. Before "
    "each decision you have looked in several directions and straight down. Straight down "
    "you see a square area whose side is twice your height: this square is your current "
    "view. You are judged on the view you stop in: its centre must be over the destination "
    "and its size should frame the destination (neither far too large nor too small). "
    "Headings and bearings are compass degrees (0 = north, 90 = east). You choose exactly "
    "one action per step, as JSON, and never anything else."
)

OUTPUT_FORMAT: Final = (
    'Output format: one JSON object {"thought": "<your reasoning, briefly>", "action": '
    '{"type": "<one of the action types>", ...its fields}} and nothing else.'
)


#: The possible actions and the output format: the same text at every step.
def action_space(fly_to: bool = True, memory: bool = True) -> str:
    """The possible actions, as the decision's schema allows them: without ``fly_to`` (an
    agent with no landmark ids to name, the NavGPT-style baseline) no such action, and
    without ``memory`` no memory node to fly to."""
    target = "an id such as L3 from the lists below" + (", or a memory node" if memory else "")
    allowed = [kind for kind in ACTION_TYPES if fly_to or kind != "fly_to"]
    return (
        "## Possible actions\n"
        f"- move_forward / move_left / move_right: distance_m (0-{MAX_MOVE_M:.0f}); one step "
        "covers at most half your view ahead (see Your drone), longer moves are shortened\n"
        "- turn: degrees (-180..180, positive = right / clockwise)\n"
        f"- ascend / descend: distance_m (0-{MAX_CLIMB_M:.0f}); height stays within "
        f"{MIN_HEIGHT_M:.0f}-{MAX_HEIGHT_M:.0f} m\n"
        + (f"- fly_to: landmark ({target}), optional height_m to arrive at\n" if fly_to else "")
        + "- waypoint: x, y in [-1, 1] (half view edges; x right, y forward) and altitude in "
        "[0, 1] (view edge 40 + 360 x altitude metres)\n"
        "- stop: you are at the destination\n"
        f"Allowed types: {', '.join(allowed)}.\n{OUTPUT_FORMAT}\n"
    )


#: The actions of the full agent.
ACTION_SPACE: Final = action_space()


def feedback_prompt(feedback: str | None, actions_taken: int, actions_left: int) -> str:
    """What the last action did, and how many actions were taken and are left (the task
    data has both: what a stand-in reads the prompt says)."""
    return (
        f"## Feedback\n{feedback or 'This is the first step.'}\n"
        f"Actions taken: {actions_taken}. Actions left before the episode ends: "
        f"{actions_left}.\n"
    )


def navigation_prompt(descriptor_text: str, memory_text: str | None, progress_text: str) -> str:
    """The spatial descriptor, the memory's clues and the sub-goal progress."""
    memory = memory_text if memory_text is not None else "(memory off)"
    return (
        f"## Landmarks around you\n{descriptor_text}\n"
        f"## Memory\n{memory}\n"
        f"## Sub-goals and progress\n{progress_text}\n"
    )


def commander_prompt(dialog: DialogText) -> str:
    """The commander's words: earlier rounds, the latest question, the current instruction."""
    return f"## Dialog with the commander\n{dialog.prose()}"


def pose_prompt(pose: ViewPose) -> str:
    """Where the drone is pointing, how high it is, what its view covers and how far one
    step reaches (half the view's edge)."""
    return (
        f"## Your drone\nHeading {pose.heading_deg:.0f} deg, height {pose.z_m:.1f} m: your "
        f"view below is a {pose.edge_m:.0f} m square; one step covers at most "
        f"{pose.edge_m / 2.0:.0f} m ahead.\n"
    )


@dataclass
class MotionResult:
    thought: str
    action: Action
    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    repaired: bool = False
    failure: ModuleFailure | None = None

    @property
    def fallback(self) -> str | None:
        return None if self.failure is None else self.failure.reason


class MotionGenerator:
    """Sends the prompts, calls the LLM, parses strictly, repairs, falls back to STOP."""

    def __init__(
        self,
        client: LLMClient,
        config: GenerationConfig,
        repair: RepairPolicy,
        module: str = "motion",
    ) -> None:
        self.client = client
        self.config = config
        self.repair = repair
        self.module = module

    def decide(
        self,
        system: str,
        user: str,
        state: dict[str, Any],
        landmark_offsets: Mapping[str, tuple[float, float]],
        images: Sequence[ImagePart] = (),
    ) -> MotionResult:
        """One decision: ``user`` is the prompt text, ``state`` the same as task data."""
        sent = tuple(images) if self.client.backend.takes_images else ()
        messages = [Message("system", system), task_message(user, self.module, state, sent)]
        config = self.config
        if config.json_schema is not None:  # fly_to may name only this decision's landmarks
            config = replace(config, json_schema=decision_json_schema(list(landmark_offsets)))
        call = call_json(
            self.client,
            self.module,
            messages,
            config,
            lambda text: parse_decision(text, landmark_offsets),
            repair=self.repair,
        )
        failure = call.failure(self.module, "stop action")
        if failure is not None or call.value is None:
            reason = call.error or "no answer"
            return MotionResult(
                thought=f"fallback: {reason}",
                action=Stop(),
                records=call.records,
                exchanges=call.exchanges,
                repaired=call.repaired,
                failure=failure,
            )
        thought, action = call.value
        return MotionResult(thought, action, call.records, call.exchanges, call.repaired)
