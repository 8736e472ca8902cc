"""Typed data crossing the LLM boundary: messages, decoding settings, completions.

The record of each call is :class:`skyvln_eval.llm_records.LlmCall`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from typing import Any, Final, Literal, get_args

Role = Literal["system", "user", "assistant"]


@dataclass(frozen=True)
class ImagePart:
    """An image sent with a message: encoded bytes (PNG or JPEG), MIME type and a label."""

    data: bytes = field(repr=False)
    mime_type: Literal["image/png", "image/jpeg"] = "image/png"
    label: str = field(default="", compare=False)  # what it shows, for logs ("view front")

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()


@dataclass(frozen=True)
class Message:
    """One chat message: text plus any images (images only where the model takes them).

    ``task_data`` is the same content as the text in machine-readable form (see
    :mod:`skyvln_eval.llm.taskdata`), for the offline stand-ins that do not read prose
    (``rule``, ``random``). It is never sent to a model server: a model reads the text,
    which says everything the data holds, once.
    """

    role: Role
    text: str
    images: tuple[ImagePart, ...] = ()
    task_data: dict[str, Any] | None = field(default=None, compare=False, hash=False)

    def fingerprint(self) -> dict[str, Any]:
        """The message as cache-key material: text verbatim, images and task data by hash."""
        out: dict[str, Any] = {
            "role": self.role,
            "text": self.text,
            "images": [i.sha256 for i in self.images],
        }
        if self.task_data is not None:
            canonical = json.dumps(self.task_data, sort_keys=True, ensure_ascii=False)
            out["task_data"] = hashlib.sha256(canonical.encode("utf-8")).hexdigest()
        return out


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


#: Levels of structured output, most to least constrained: the OpenAI ``json_schema``
#: response format (strict), ``json_object`` with the schema attached (llama.cpp and
#: others constrain decoding by it), plain ``json_object``, and no response format at all
#: (the prompt asks for JSON and the parser checks it).
StructuredLevel = Literal["json_schema", "json_object_schema", "json_object", "prompt"]
STRUCTURED_LEVELS: tuple[StructuredLevel, ...] = get_args(StructuredLevel)


@dataclass(frozen=True)
class RefusedRequest:
    """A request the server turned down for its form, after which the backend sent the
    call again at once in another form: a structured-output level it does not take, or a
    decoding parameter the model refuses.

    It is a request all the same (it went over the wire, took time, may have been billed),
    so the client records it as an attempt of its own (outcome ``refused``), never folded
    into the answer's latency. ``structured_output`` and ``server_defaults`` are the level
    and the unsent parameters of the refused request; ``error`` what the server said (any
    API key scrubbed); tokens are ``None`` unless the server reported some.
    """

    error: str
    latency_s: float
    structured_output: StructuredLevel | None = None
    server_defaults: tuple[str, ...] = ()
    prompt_tokens: int | None = None
    completion_tokens: int | None = None


#: Finish reasons of a text that is no answer: a content filter's stop, the model's refusal
#: (OpenAI's structured outputs), an answer cut off at its budget.
NOT_ANSWERS: Final = frozenset({"content_filter", "refusal", "length"})


@dataclass(frozen=True)
class Completion:
    """A backend's answer to one call, with its usage and timing.

    Token counts are ``None`` when the server did not report them (or reported a prompt of
    0 tokens, which no request has). ``cached_prompt_tokens`` is the part of the prompt a
    provider's prompt cache served (billed at a discount), ``reasoning_tokens`` the part
    of the completion a reasoning model spent thinking (billed, never shown).
    ``finish_reason`` is the server's (``None``: it gave none); the offline backends say
    ``"stop"``. ``structured_output``
    is the level of structured output the request used (``None``: the call asked for
    free text); ``server_defaults`` the decoding parameters of the call that were not sent
    because the model refuses them (it decoded at the server's defaults). ``latency_s`` is
    the time of the request that was answered only; ``refused`` lists the requests of the
    same call the server turned down for their form before it (negotiation), each with its
    own time. The response cache does not keep ``refused``: a cached answer stands for its
    answer only.
    """

    text: str
    backend: str
    model: str
    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    cached_prompt_tokens: int | None = None
    reasoning_tokens: int | None = None
    latency_s: float = 0.0
    finish_reason: str | None = "stop"
    cached: bool = False
    structured_output: StructuredLevel | None = None
    server_defaults: tuple[str, ...] = ()
    refused: tuple[RefusedRequest, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.text, str):  # a cache entry or a backend gone wrong
            raise TypeError(f"a completion's text is a string, got {type(self.text).__name__}")

    @property
    def is_answer(self) -> bool:
        """Whether the model answered something: not an empty text, not a server's filter
        stopping it, not the model declining (``refusal``), not an answer cut off at its
        budget (``length``). Only answers are cached: a non-answer asked again may get one."""
        return bool(self.text.strip()) and self.finish_reason not in NOT_ANSWERS
