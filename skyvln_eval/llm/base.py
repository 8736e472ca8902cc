"""The one interface every LLM backend implements, and how tables label backends."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any, Literal

from skyvln_eval.llm.types import Completion, GenerationConfig, Message

#: What a backend is. Only ``llm`` backends are language models; tables must show the others
#: as what they are (a rule-based stand-in, a random baseline, a script, a cache replay).
BackendKind = Literal["llm", "rule", "random", "scripted", "replay"]

KIND_LABELS: dict[str, str] = {
    "llm": "LLM",
    "rule": "rule-based (not an LLM)",
    "random": "random (not an LLM)",
    "scripted": "scripted (test double)",
    "replay": "replay of cached LLM answers",
}


class LLMBackend(ABC):
    """``generate(messages, config) -> Completion``; everything else has a default.

    ``name`` is the registry name (``"openai"``, ``"rule"``, ...), ``model`` the model
    identity; :meth:`identity` is what the response cache keys on, model identity first.
    Backends raise :class:`~skyvln_eval.errors.LLMTransientError` for faults worth retrying
    and :class:`~skyvln_eval.errors.LLMError` for the others; retries, caching and
    accounting happen around them (:class:`~skyvln_eval.llm.client.LLMClient`).
    """

    name: str = "backend"
    kind: BackendKind = "llm"
    model: str = ""
    takes_images: bool = False
    #: Whether answers are computed by Python in this process (no server to wait for):
    #: the agent then makes its independent calls one after another, as threads would
    #: only take turns on the interpreter's lock (and cost a pool per decision).
    answers_in_process: bool = False

    @classmethod
    def checked_model(cls, model: str | None) -> str | None:
        """``model`` (what follows ``<name>:`` in a spec; ``None``: nothing), or the
        :class:`~skyvln_eval.errors.ConfigError` saying why it names none of this backend's
        models. The constructor calls it, and a config's validation before any backend is
        made (:func:`~skyvln_eval.llm.registry.check_spec`). Default: any model, or none."""
        return model

    def missing_key(self) -> str | None:
        """What to set when this backend needs an API key the environment does not hold
        (checked before a run starts: otherwise its first call stops it), else ``None``.
        Default: none needed."""
        return None

    @abstractmethod
    def generate(self, messages: Sequence[Message], config: GenerationConfig) -> Completion:
        """One completion for ``messages``."""

    def identity(self) -> dict[str, Any]:
        """Cache-key identity: which backend and model (and server) would answer."""
        return {"backend": self.name, "model": self.model}

    @property
    def label(self) -> str:
        """How a results table names this backend, e.g. ``rule (rule-based (not an LLM))``."""
        shown = f"{self.name}:{self.model}" if self.model else self.name
        return f"{shown} [{KIND_LABELS[self.kind]}]"
