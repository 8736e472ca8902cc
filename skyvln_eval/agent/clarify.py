"""Asking the commander: the LLM turns what went wrong into one clarification question.

TrackBack memory asks when a landmark the agent flew to was not there, and, when HSD's
descriptions match two candidates for a stop landmark equally well, which one (the
paper's clarification prompt is the memory's: without it the agent never asks). The
question goes to the harness, whose simulated commander may answer it (within a budget);
the answer joins the dialog the agent sees at its next step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Final

from skyvln_eval.agent.calls import call_json
from skyvln_eval.agent.motion import SYSTEM_PROMPT
from skyvln_eval.agent.parsing import load_json_object, refuse_other_fields
from skyvln_eval.errors import ActionParseError
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig
from skyvln_eval.llm.taskdata import task_message
from skyvln_eval.llm.types import Message
from skyvln_eval.llm_records import LlmCall, ModuleFailure

MAX_QUESTION_CHARS: Final = 500
QUESTION_SCHEMA: Final[dict[str, Any]] = {
    "type": "object",
    "properties": {"question": {"type": "string", "minLength": 1, "maxLength": MAX_QUESTION_CHARS}},
    "required": ["question"],
    "additionalProperties": False,
}


@dataclass
class Clarification:
    """The question (``None`` if none could be formulated) and what asking cost."""

    question: str | None = None
    records: list[LlmCall] = field(default_factory=list)
    exchanges: list[dict[str, Any]] = field(default_factory=list)
    failures: list[ModuleFailure] = field(default_factory=list)


def _parse_question(text: str) -> str:
    data = load_json_object(text)
    refuse_other_fields(data, ("question",))
    question = data.get("question")
    if not isinstance(question, str) or not 0 < len(question) <= MAX_QUESTION_CHARS:
        raise ActionParseError(
            f"'question' must be a non-empty string of at most {MAX_QUESTION_CHARS} characters"
        )
    return question


def ask_commander(
    client: LLMClient, llm: LLMConfig, reason: str, goal: str | None, memory: str | None
) -> Clarification:
    """One short question for the commander about ``reason`` (module ``clarify``)."""
    data = {"reason": reason, "goal": goal, "memory": memory}
    prose = (
        f"You are unsure: {reason}."
        + (f" You are looking for {goal!r}." if goal else "")
        + (f" Your memory: {memory}" if memory else "")
        + " Formulate one short clarification question for the commander. Answer as "
        '{"question": "..."}.\n'
    )
    messages = [Message("system", SYSTEM_PROMPT), task_message(prose, "clarify", data)]
    config = llm.generation("clarify", json_schema=QUESTION_SCHEMA, schema_name="question")
    call = call_json(client, "clarify", messages, config, _parse_question, llm.repair_policy())
    failure = call.failure("clarify", "no question asked")
    return Clarification(
        call.value, call.records, call.exchanges, [failure] if failure is not None else []
    )
