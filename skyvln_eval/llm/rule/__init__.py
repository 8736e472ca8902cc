"""The ``rule`` backend: a deterministic offline stand-in for an LLM. It is not an LLM.

It reads only the task data of the agent's requests (:mod:`skyvln_eval.llm.taskdata`)
and answers each task in the JSON an LLM is asked for, so the whole SkyVLN pipeline runs
and navigates sensibly without a network: sub-goals read with a vocabulary, not sentence
patterns (:mod:`.instructions`), HSD descriptions and rankings from attribute comparison
(:mod:`.matching`), motions from landmarks, headings and distances (:mod:`.navigation`).
Tables label it ``rule-based (not an LLM)`` (its ``kind`` is ``"rule"``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from skyvln_eval.errors import ConfigError, LLMError
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.rule.instructions import landmark_phrases, parse_instruction
from skyvln_eval.llm.rule.matching import describe, rank
from skyvln_eval.llm.rule.navigation import decide_motion, decide_navgpt
from skyvln_eval.llm.taskdata import read_task_data
from skyvln_eval.llm.types import Completion, GenerationConfig, Message

RULE_MODEL = "rule-v1"


def _subgoals(data: dict[str, Any]) -> dict[str, Any]:
    context: list[str] = []
    for text in data.get("previous_rounds", []):
        context += [p for p in landmark_phrases(text) if p not in context]
    return {
        "subgoals": parse_instruction(
            data.get("instruction") or "", data.get("question"), data.get("heading_deg")
        ),
        "context_landmarks": context,
    }


def _clarify(data: dict[str, Any]) -> dict[str, Any]:
    reason = data.get("reason", "I am not sure where I am")
    goal = data.get("goal")
    about = f" Is {goal!r} somewhere else?" if goal else ""
    # The reason is the agent's (a landmark that was not there, two that look alike): the
    # question says it as given, and nothing it did not do ("I went back" was said always).
    return {"question": f"I am not sure of the way: {reason}.{about} Where should I head now?"}


class RuleBackend(LLMBackend):
    """See the module docstring."""

    name = "rule"
    kind = "rule"
    answers_in_process = True

    def __init__(self, model: str | None = None) -> None:
        self.checked_model(model)
        self.model = RULE_MODEL

    @classmethod
    def checked_model(cls, model: str | None) -> str:
        if model not in (None, RULE_MODEL):
            raise ConfigError(f"the rule backend has one version, {RULE_MODEL!r}; got {model!r}")
        return RULE_MODEL

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        data = read_task_data(messages)
        handlers = {
            "subgoals": _subgoals,
            "hsd_describe": describe,
            "hsd_rank": rank,
            "motion": decide_motion,
            "navgpt": decide_navgpt,
            "clarify": _clarify,
        }
        task = data["task"]
        if task not in handlers:
            raise LLMError(f"the rule backend has no answer for task {task!r}")
        text = json.dumps(handlers[task](data))
        # Not a model: no tokenizer. Four characters a token, as the offline estimate.
        prompt_chars = sum(len(m.text) for m in messages)
        return Completion(
            text=text,
            backend=self.name,
            model=self.model,
            prompt_tokens=max(1, prompt_chars // 4),
            completion_tokens=max(1, len(text) // 4),
        )
