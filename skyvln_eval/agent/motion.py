"""The LLM motion generator: system, action and navigation prompts -> thought and one action.

* System prompt: the embodiment (a drone, its camera, what its views mean, how it is judged).
* Action prompt: feedback on the last action, the possible actions with their limits at
  the current height, and the output format.
* Navigation prompt: the spatial descriptor's text (HSD or coarse), TrackBack memory's
  clues, and the sub-goals with their progress; then the TASK DATA block.

The answer must be ``{"thought": ..., "action": {...}}`` (see :mod:`.parsing`). An
unusable answer is sent back once for repair; if the repair fails too, or the backend
gives up, the safe fallback action (STOP: hover and end the episode where it is) is taken
and the reason recorded in the trace.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from skyvln_eval.agent.actions import (
    ACTION_TYPES,
    MAX_CLIMB_M,
    MAX_HEIGHT_M,
    MAX_MOVE_M,
    MIN_HEIGHT_M,
    Action,
    Stop,
)
from skyvln_eval.agent.calls import call_json
from skyvln_eval.agent.parsing import parse_decision
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.taskdata import task_block
from skyvln_eval.llm.types import GenerationConfig, ImagePart, LLMCallRecord, Message

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


def action_prompt(feedback: str | None, reach_m: float, actions_left: int) -> str:
    """Feedback, the possible actions with their limits, and the output format."""
    return (
        f"## Feedback\n{feedback or 'This is the first step.'}\n"
        f"## Possible actions ({actions_left} left before the episode ends)\n"
        f"- move_forward / move_left / move_right: distance_m (0-{MAX_MOVE_M:.0f}); one step "
        f"covers at most {reach_m:.0f} m ahead (half your view), longer moves are shortened\n"
        "- turn: degrees (-180..180, positive = right / clockwise)\n"
        f"- ascend / descend: distance_m (0-{MAX_CLIMB_M:.0f}); height stays within "
        f"{MIN_HEIGHT_M:.0f}-{MAX_HEIGHT_M:.0f} m\n"
        "- fly_to: landmark (an id such as L3 from the lists below, or a memory node), "
        "optional height_m to arrive at\n"
        "- waypoint: x, y in [-1, 1] (half view edges; x right, y forward) and altitude in "
        "[0, 1] (view edge 40 + 360 x altitude metres)\n"
        "- stop: you are at the destination\n"
        f"Allowed types: {', '.join(ACTION_TYPES)}.\n{OUTPUT_FORMAT}\n"
    )


def navigation_prompt(descriptor_text: str, memory_text: str | None, progress_text: str) -> str:
    """The spatial descriptor, the memory's clues and the sub-goal progress."""
    memory = memory_text if memory_text is not None else "(memory off)"
    return (
        f"## Landmarks around you\n{descriptor_text}\n"
        f"## Memory\n{memory}\n"
        f"## Sub-goals and progress\n{progress_text}\n"
    )


@dataclass
class MotionResult:
    thought: str
    action: Action
    records: list[LLMCallRecord] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    repaired: bool = False
    fallback: str | None = None


class MotionGenerator:
    """Builds the three prompts, calls the LLM, parses strictly, repairs once, falls back."""

    def __init__(self, client: LLMClient, config: GenerationConfig, module: str = "motion") -> None:
        self.client = client
        self.config = config
        self.module = module

    def decide(
        self,
        system: str,
        user: str,
        task: str,
        state: dict[str, Any],
        landmark_offsets: Mapping[str, tuple[float, float]],
        images: Sequence[ImagePart] = (),
    ) -> MotionResult:
        messages = [
            Message("system", system),
            Message(
                "user",
                user + task_block(task, state),
                tuple(images) if self.client.backend.takes_images else (),
            ),
        ]
        call = call_json(
            self.client,
            self.module,
            messages,
            self.config,
            lambda text: parse_decision(text, landmark_offsets),
            repair=True,
        )
        if call.value is None:
            reason = call.error or "no answer"
            return MotionResult(
                thought=f"fallback: {reason}",
                action=Stop(),
                records=call.records,
                exchanges=call.exchanges,
                repaired=call.repaired,
                fallback=reason,
            )
        thought, action = call.value
        return MotionResult(thought, action, call.records, call.exchanges, call.repaired)
