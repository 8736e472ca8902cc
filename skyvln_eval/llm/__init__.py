"""LLM backends behind one interface, with a response cache, retries and cost accounting.

``create_backend("openai:gpt-4o")`` (or ``"rule"``, ``"random"``, ``"scripted"``,
``"replay:openai:gpt-4o"``) gives an :class:`LLMBackend`; an :class:`LLMClient` wraps it with
the SQLite :class:`ResponseCache`, a :class:`RetryPolicy`, a concurrency limit and the price
table, and returns an :class:`LlmCall` record per attempt. Importing this package imports no
backend's dependencies (``openai`` is imported when an openai backend first calls).
"""

from skyvln_eval.llm.base import KIND_LABELS, BackendKind, LLMBackend
from skyvln_eval.llm.cache import ResponseCache, cache_key
from skyvln_eval.llm.client import CallResult, LLMClient
from skyvln_eval.llm.config import LLMConfig, RetryConfig, build_client
from skyvln_eval.llm.negotiation import negotiated_levels
from skyvln_eval.llm.prices import Price, PriceTable, load_prices
from skyvln_eval.llm.registry import (
    backend_identity,
    create_backend,
    known_backends,
    register_backend,
)
from skyvln_eval.llm.retry import RetryPolicy
from skyvln_eval.llm.taskdata import read_task_data, task_message
from skyvln_eval.llm.types import (
    STRUCTURED_LEVELS,
    Completion,
    GenerationConfig,
    ImagePart,
    Message,
    StructuredLevel,
)
from skyvln_eval.llm_records import LlmCall, ModuleFailure

__all__ = [
    "KIND_LABELS",
    "STRUCTURED_LEVELS",
    "BackendKind",
    "CallResult",
    "Completion",
    "GenerationConfig",
    "ImagePart",
    "LLMBackend",
    "LLMClient",
    "LLMConfig",
    "LlmCall",
    "Message",
    "ModuleFailure",
    "Price",
    "PriceTable",
    "ResponseCache",
    "RetryConfig",
    "RetryPolicy",
    "StructuredLevel",
    "backend_identity",
    "build_client",
    "cache_key",
    "create_backend",
    "known_backends",
    "load_prices",
    "negotiated_levels",
    "read_task_data",
    "register_backend",
    "task_message",
]
