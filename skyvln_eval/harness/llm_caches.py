"""Where a run's LLM response caches are, and whether they can be used.

A relative ``cache_path`` is taken inside the run's output folder, by the rule plans
follow (:func:`~skyvln_eval.llm.cache.resolve_cache_path`), not in the working directory.
The run's config keeps the path as written: its digest, which a resume checks, does not
depend on where the run directory is; only the clients built from it are placed
(:func:`caches_in`).

Before any episode runs, each cache the agent's models use is opened once
(:func:`cache_notes`): a replay whose cache cannot be opened is refused with the reason
(every call would miss, blaming the cache's contents), and a cache that can only be read
is said in the run's notes (its answers are served, new ones not stored), as is one that
cannot be used at all (the run goes on without it).
"""

from __future__ import annotations

from pathlib import Path

from skyvln_eval.agent.config import AgentConfig, models_called
from skyvln_eval.errors import ConfigError
from skyvln_eval.llm.cache import ResponseCache, resolve_cache_path
from skyvln_eval.llm.config import LLMConfig


def _placed(llm: LLMConfig, out_dir: str | Path) -> LLMConfig:
    if not llm.cache_path:
        return llm
    return llm.model_copy(update={"cache_path": resolve_cache_path(llm.cache_path, out_dir)})


def caches_in(agent: AgentConfig, out_dir: str | Path) -> AgentConfig:
    """``agent`` with each model's relative ``cache_path`` (its own, its VLM detector's)
    taken inside ``out_dir``."""
    detector = agent.detector
    if detector.llm is not None:
        detector = detector.model_copy(update={"llm": _placed(detector.llm, out_dir)})
    return agent.model_copy(update={"llm": _placed(agent.llm, out_dir), "detector": detector})


def cache_notes(agent: AgentConfig, out_dir: str | Path, source: str) -> list[str]:
    """Open the caches ``agent``'s models use (placed in ``out_dir``): refuse a replay
    whose cache cannot be opened (``ConfigError``, naming ``source`` and the reason);
    a note for each other cache that cannot be opened, or can only be read."""
    notes = []
    for field, llm in models_called(caches_in(agent, out_dir)).items():
        if not llm.cache_path:
            continue
        cache = ResponseCache(llm.cache_path)
        try:
            if not cache.usable and llm.backend.startswith("replay:"):
                raise ConfigError(
                    f"{source}: {field}: {llm.backend} answers only from its response cache, "
                    f"and {llm.cache_path} cannot be opened ({cache.problem})"
                )
            if not cache.usable:
                notes.append(
                    f"{field}: the LLM response cache {llm.cache_path} cannot be opened "
                    f"({cache.problem}): answers are neither read from it nor stored"
                )
            elif cache.read_only:
                notes.append(
                    f"{field}: the LLM response cache {llm.cache_path} cannot be written "
                    f"({cache.problem}): its answers are read from it, new answers are not "
                    "stored"
                )
        finally:
            cache.close()
    return notes
