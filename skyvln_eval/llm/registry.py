"""The lazy backend registry: ``openai:<model>``, ``rule``, ``random``, ``scripted``, ``replay``.

A spec is ``<name>[:<model>]``. Names map to ``"module:Class"`` strings imported only when
a backend is created, so importing the toolkit never imports ``openai``. Register your
own with :func:`register_backend`; an unknown name says "did you mean ...".
"""

from __future__ import annotations

import importlib
from typing import Any

from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.llm.base import LLMBackend

_REGISTRY: dict[str, str | type[LLMBackend]] = {
    "openai": "skyvln_eval.llm.openai_backend:OpenAIBackend",
    "rule": "skyvln_eval.llm.rule:RuleBackend",
    "random": "skyvln_eval.llm.simple:RandomBackend",
    "scripted": "skyvln_eval.llm.simple:ScriptedBackend",
    "replay": "skyvln_eval.llm.simple:ReplayBackend",
}


def register_backend(name: str, target: str | type[LLMBackend]) -> None:
    """Register a backend class, or its ``"module:Class"`` path to import on first use."""
    if not name or ":" in name:
        raise ConfigError(f"backend name must be non-empty and without ':', got {name!r}")
    _REGISTRY[name] = target


def known_backends() -> list[str]:
    return sorted(_REGISTRY)


def _resolve(name: str) -> type[LLMBackend]:
    if name not in _REGISTRY:
        raise UnknownNameError("LLM backend", name, known_backends())
    target = _REGISTRY[name]
    if isinstance(target, str):
        module_name, _, class_name = target.partition(":")
        target = getattr(importlib.import_module(module_name), class_name)
        _REGISTRY[name] = target
    if not (isinstance(target, type) and issubclass(target, LLMBackend)):
        raise ConfigError(f"registered backend {name!r} is not an LLMBackend subclass")
    return target


def check_spec(spec: str) -> None:
    """Raise the :class:`ConfigError` :func:`create_backend` would for ``spec``'s name or
    model, without making the backend (nor importing its optional dependencies)."""
    name, _, model = spec.partition(":")
    _resolve(name).checked_model(model or None)


def create_backend(spec: str, **options: Any) -> LLMBackend:
    """A backend from its spec, e.g. ``create_backend("openai:gpt-4o", base_url=...)``.

    ``options`` go to the backend's constructor (``base_url``, ``api_key_env``, ...).
    """
    name, _, model = spec.partition(":")
    cls = _resolve(name)
    try:
        return cls(model=model or None, **options)  # type: ignore[call-arg]
    except TypeError as error:
        raise ConfigError(f"backend {spec!r} does not take these options: {error}") from error


def backend_identity(spec: str, base_url: str | None = None, **options: Any) -> dict[str, Any]:
    """The cache identity the backend ``spec`` would have with ``options`` (used by
    ``replay``)."""
    if base_url is not None:
        options["base_url"] = base_url
    return create_backend(spec, **options).identity()
