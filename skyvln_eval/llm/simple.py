"""Backends that are not language models: scripted (tests), random, and cache replay."""

from __future__ import annotations

import json
import random
import zlib
from collections.abc import Callable, Sequence
from typing import Any

from skyvln_eval.errors import CacheMissError, ConfigError, LLMError
from skyvln_eval.llm.base import LLMBackend
from skyvln_eval.llm.taskdata import read_task_data
from skyvln_eval.llm.types import Completion, GenerationConfig, Message
from skyvln_eval.vocabulary import COMPASS

ScriptItem = str | Exception | Callable[[Sequence[Message]], str]


def _tokens(text: str) -> int:
    """A rough token count (4 characters a token) for backends without a tokenizer."""
    return max(1, len(text) // 4)


def _completion(backend: LLMBackend, messages: Sequence[Message], text: str) -> Completion:
    return Completion(
        text=text,
        backend=backend.name,
        model=backend.model,
        prompt_tokens=sum(_tokens(m.text) for m in messages),
        completion_tokens=_tokens(text),
    )


class ScriptedBackend(LLMBackend):
    """Answers from a script, in order: a string is returned, an exception raised, a
    callable called with the messages. Running out of script is an :class:`LLMError`."""

    name = "scripted"
    kind = "scripted"

    def __init__(self, script: Sequence[ScriptItem] = (), model: str | None = None) -> None:
        self.model = model or "script"
        self.script = list(script)
        self.calls: list[list[Message]] = []

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        self.calls.append(list(messages))
        if not self.script:
            raise LLMError(
                f"scripted backend ran out of answers after {len(self.calls) - 1} call(s)"
            )
        item = self.script.pop(0)
        if isinstance(item, Exception):
            raise item
        text = item(messages) if callable(item) else item
        return _completion(self, messages, text)


class RandomBackend(LLMBackend):
    """Valid but random answers to the agent's tasks: a floor for comparisons, not an LLM.

    Seeded by ``config.seed`` and the prompt, so identical calls get identical answers.
    """

    name = "random"
    kind = "random"
    answers_in_process = True

    def __init__(self, model: str | None = None) -> None:
        self.model = model or "uniform"

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        data = read_task_data(messages)
        seed = zlib.crc32(json.dumps(data, sort_keys=True).encode()) ^ (config.seed or 0)
        rng = random.Random(seed)
        task = data["task"]
        answer: dict[str, Any]
        if task == "subgoals":
            # One random heading: a plan may not be empty when the instruction has words.
            answer = {"subgoals": [{"kind": "head", "direction": rng.choice(sorted(COMPASS))}]}
        elif task == "hsd_describe":
            answer = {
                "description": "no opinion",
                "match": rng.choice(["strong", "partial", "none"]),
            }
        elif task == "hsd_rank":
            ids = [c["id"] for c in data.get("candidates", [])]
            rng.shuffle(ids)
            answer = {"ranking": ids, "best": ids[0] if ids else None, "confidence": rng.random()}
        elif task == "clarify":
            answer = {"question": "Where should I go?"}
        else:
            answer = {"thought": "random choice", "action": random_action(rng, data)}
        return _completion(self, messages, json.dumps(answer))


def random_action(rng: random.Random, data: dict[str, Any]) -> dict[str, Any]:
    """A uniformly chosen action of the vocabulary with random parameters."""
    kind = rng.choice(
        ["move_forward", "move_left", "move_right", "turn", "ascend", "descend", "waypoint", "stop"]
    )
    if kind.startswith("move_"):
        return {"type": kind, "distance_m": round(rng.uniform(10, 120), 1)}
    if kind == "turn":
        return {"type": kind, "degrees": round(rng.uniform(-180, 180), 1)}
    if kind in ("ascend", "descend"):
        return {"type": kind, "distance_m": round(rng.uniform(5, 40), 1)}
    if kind == "waypoint":
        return {
            "type": kind,
            "x": round(rng.uniform(-1, 1), 3),
            "y": round(rng.uniform(-1, 1), 3),
            "altitude": round(rng.uniform(0, 1), 3),
        }
    return {"type": "stop"}


class ReplayBackend(LLMBackend):
    """Answers only from the response cache, as the replayed backend answered.

    ``of`` is the replayed registry spec (``"openai:gpt-4o"``), ``base_url`` its server
    and ``system_role`` and ``extra_body`` its settings, so the cache keys match the
    original run's. The cache lookup happens in
    :class:`~skyvln_eval.llm.client.LLMClient`; reaching :meth:`generate` means a miss.
    """

    name = "replay"
    kind = "replay"
    answers_in_process = True

    def __init__(
        self,
        model: str | None = None,
        base_url: str | None = None,
        system_role: bool = True,
        extra_body: dict[str, Any] | None = None,
        send_task_data: bool = False,
        structured_output: str = "auto",
    ) -> None:
        from skyvln_eval.llm.registry import backend_identity

        model = self.checked_model(model)
        self.model = model
        options: dict[str, Any] = {} if system_role else {"system_role": False}  # openai's
        if extra_body:
            options["extra_body"] = extra_body
        if send_task_data:  # the answers of a server sent the task data: replayed as such
            options["send_task_data"] = True
        if structured_output != "auto":  # the answers of a run pinned to a level
            options["structured_output"] = structured_output
        self._identity = backend_identity(model, base_url=base_url, **options)

    @classmethod
    def checked_model(cls, model: str | None) -> str:
        """The replayed backend's spec, itself checked: 'replay:openai:' has no model."""
        if not model:
            raise ConfigError(
                "replay needs the replayed backend: 'replay:<backend>:<model>', "
                "e.g. 'replay:openai:gpt-4o'"
            )
        from skyvln_eval.llm.registry import check_spec

        check_spec(model)
        return model

    def identity(self) -> dict[str, Any]:
        return dict(self._identity)

    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        raise CacheMissError(
            f"replay of {self.model}: no cached answer for this call (a changed prompt, "
            "decoding setting, model or server, or an empty cache); run once with the "
            "real backend and the same cache path to record it"
        )
