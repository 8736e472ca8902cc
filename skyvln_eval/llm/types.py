"""Typed data crossing the LLM boundary: messages, decoding settings, completions, call records."""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

Role = Literal["system", "user", "assistant"]


@dataclass(frozen=True)
class ImagePart:
    """An image sent with a message: encoded bytes (PNG or JPEG) and their MIME type."""

    data: bytes = field(repr=False)
    mime_type: Literal["image/png", "image/jpeg"] = "image/png"

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()


@dataclass(frozen=True)
class Message:
    """One chat message: text plus any images (images only where the model takes them)."""

    role: Role
    text: str
    images: tuple[ImagePart, ...] = ()

    def fingerprint(self) -> dict[str, Any]:
        """The message as cache-key material: text verbatim, images by content hash."""
        return {"role": self.role, "text": self.text, "images": [i.sha256 for i in self.images]}


@dataclass(frozen=True)
class GenerationConfig:
    """Decoding settings of one call; every field is part of the cache key.

    ``json_schema`` is the output schema to request as structured output (``None`` =
    free text); ``timeout_s`` bounds one HTTP attempt. ``seed`` is passed to servers that
    support it (OpenAI, vLLM, llama.cpp) and seeds the ``random`` backend.
    """

    temperature: float = 0.0
    top_p: float = 1.0
    max_tokens: int = 512
    seed: int | None = 0
    stop: tuple[str, ...] = ()
    json_schema: dict[str, Any] | None = None
    schema_name: str = "output"
    timeout_s: float = 60.0

    def key_material(self) -> dict[str, Any]:
        """Everything that can change the answer (the timeout cannot, so it is left out)."""
        out = asdict(self)
        out.pop("timeout_s")
        out["stop"] = list(self.stop)
        return out


@dataclass(frozen=True)
class Completion:
    """A backend's answer to one call, with its usage and timing."""

    text: str
    backend: str
    model: str
    prompt_tokens: int = 0
    completion_tokens: int = 0
    latency_s: float = 0.0
    finish_reason: str = "stop"
    cached: bool = False
    structured: bool = False  # the server honoured the requested JSON schema


@dataclass(frozen=True)
class LLMCallRecord:
    """What one LLM call (or one failed attempt) cost, for accounting per agent module.

    ``module`` names the agent part that made the call (``subgoals``, ``hsd_describe``,
    ``hsd_rank``, ``motion``, ``motion_repair``, ``clarify``, ``navgpt``); ``cost_usd`` is
    ``None`` when the price table has no entry for the model; ``error`` says what went
    wrong (a transport fault that was retried, or output the agent could not use).
    """

    module: str
    backend: str
    model: str
    prompt_tokens: int
    completion_tokens: int
    cost_usd: float | None
    latency_s: float
    cached: bool
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
