"""The real local LLM server (llama.cpp + Gemma 3 270M) for the tests that need a real model."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from skyvln_eval.llm.local_server import find_local_llama, local_llama_server
from skyvln_eval.llm.negotiation import forget_levels


@pytest.fixture(autouse=True)
def _fresh_negotiation() -> Iterator[None]:
    """Each test negotiates structured output afresh (the levels are per process)."""
    forget_levels()
    yield
    forget_levels()


@pytest.fixture(scope="session")
def local_llm_url() -> Iterator[str]:
    """The ``/v1`` base URL of a llama.cpp server on 127.0.0.1, started once per session.

    Skipped, with what is missing, when llama-cpp-python or the GGUF package is not
    installed (the ``local-llm`` extra, or ``$SKYVLN_EVAL_LLAMA_PYTHON``).

    When other test workers share the machine (pytest-xdist), the server computes in one
    thread: on all cores it starved the other worker's tests, whose 0.5 s deadlines then
    ran out (measured in CI: an extra timeout in test_agent_faults).
    """
    llama = find_local_llama()
    if isinstance(llama, str):
        pytest.skip(f"no real local LLM: {llama}")
    threads = 1 if os.environ.get("PYTEST_XDIST_WORKER") else None
    with local_llama_server(llama, n_threads=threads) as base_url:
        yield base_url
