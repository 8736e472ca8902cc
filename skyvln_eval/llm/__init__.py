"""LLM backends behind one interface, with a response cache, retries and cost accounting.

``create_backend("openai:gpt-4o")`` (or ``"rule"``, ``"random"``, ``"scripted"``,
``"replay:openai:gpt-4o"``) gives an :class:`LLMBackend`; an :class:`LLMClient` wraps it with
the SQLite :class:`ResponseCache`, a :class:`RetryPolicy`, a concurrency limit and the price
table, and returns an :class:`LLMCallRecord` per attempt. Importing this package imports no
backend's dependencies (``openai`` is imported when an openai backend first calls).
"""

from skyvln_eval.llm.base import KIND_LABELS, BackendKind, LLMBackend
from skyvln_eval.llm.cache import ResponseCache, cache_key
from skyvln_eval.llm.client import CallResult, LLMClient
from skyvln_eval.llm.config import LLMConfig, RetryConfig, build_client
from skyvln_eval.llm.prices import Price, PriceTable, load_prices
from skyvln_eval.llm.registry import (
    backend_identity,
    create_backend,
    known_backends,
    register_backend,
)
from skyvln_eval.llm.retry import RetryPolicy
from skyvln_eval.llm.taskdata import read_task_block, task_block
from skyvln_eval.llm.types import Completion, GenerationConfig, ImagePart, LLMCallRecord, Message

__all__ = [
    "KIND_LABELS",
    "BackendKind",
    "CallResult",
    "Completion",
    "GenerationConfig",
    "ImagePart",
    "LLMBackend",
    "LLMCallRecord",
    "LLMClient",
    "LLMConfig",
    "Message",
    "Price",
    "PriceTable",
    "ResponseCache",
    "RetryConfig",
    "RetryPolicy",
    "backend_identity",
    "build_client",
    "cache_key",
    "create_backend",
    "known_backends",
    "load_prices",
    "read_task_block",
    "register_backend",
    "task_block",
]
