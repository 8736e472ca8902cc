"""One backend configuration for every way of naming a backend: a backends file and specs.

A backends file (YAML) names complete backend configurations, with defaults for all::

    format: skyvln-eval/llm-backends
    version: 1
    defaults: {timeout_s: 120, max_concurrency: 8, cache_path: llm-cache.sqlite}
    backends:
      gpt-4o-mini: {backend: "openai:gpt-4o-mini"}
      local-gemma:
        backend: "openai:gemma-3-270m"
        base_url: "http://127.0.0.1:8765/v1"
        structured_output: json_object_schema
        system_role: false

An entry of ``$SKYVLN_EVAL_BACKENDS`` (comma-separated) is either the name of such a
backend or a spec ``openai:<model>[@<base_url>]``; both resolve to a full
:class:`~skyvln_eval.llm.config.LLMConfig` (cache, timeout, key variable, structured
output, prices, concurrency, images), the spec with the file's defaults. The API key is
never in the file: ``api_key_env`` names the variable it is read from. A server's URL
with credentials or a query is refused, in a file and in a spec (it would be the Table II
row's label), and messages show it redacted.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import yaml
from pydantic import ValidationError

from skyvln_eval.errors import ConfigError, UnknownNameError, describe_validation_error
from skyvln_eval.fileio import load_yaml
from skyvln_eval.llm.config import LLMConfig, shown_backend

BACKENDS_FORMAT: Final = "skyvln-eval/llm-backends"
BACKENDS_VERSION: Final = 1
#: The environment variable that names a backends file for ``$SKYVLN_EVAL_BACKENDS``.
BACKENDS_FILE_ENV: Final = "SKYVLN_EVAL_BACKENDS_FILE"
#: An ``openai:<model>[@<base_url>]`` entry; :class:`LLMConfig` itself parses it (the
#: server is what follows the last '@' when it is a URL: '@' may be part of a model id).
_SPEC = re.compile(r"openai:\S+")


@dataclass(frozen=True)
class BackendsFile:
    """Named backend configurations and the defaults a bare spec gets."""

    path: str | None = None
    defaults: dict[str, Any] = field(default_factory=dict)
    backends: dict[str, LLMConfig] = field(default_factory=dict)


def _config(data: dict[str, Any], where: str) -> LLMConfig:
    try:
        return LLMConfig.model_validate(data)
    except ValidationError as error:
        raise ConfigError(f"{where}: {describe_validation_error(error, LLMConfig)}") from None


def load_backends_file(path: str | Path) -> BackendsFile:
    """Read and validate a backends file; errors name the file, the backend and the field."""
    file = Path(path)
    try:
        data = load_yaml(file.read_text(encoding="utf-8"), file)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise ConfigError(f"backends file {file}: {error}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"backends file {file}: must be a mapping with 'backends'")
    if data.get("format") != BACKENDS_FORMAT or data.get("version") != BACKENDS_VERSION:
        raise ConfigError(
            f"backends file {file}: needs 'format: {BACKENDS_FORMAT}' and "
            f"'version: {BACKENDS_VERSION}'"
        )
    unknown = sorted(set(data) - {"format", "version", "defaults", "backends"})
    if unknown:
        raise ConfigError(f"backends file {file}: unknown key(s) {unknown}")
    defaults = data.get("defaults") or {}
    entries = data.get("backends") or {}
    if not isinstance(defaults, dict) or not isinstance(entries, dict):
        raise ConfigError(f"backends file {file}: 'defaults' and 'backends' must be mappings")
    _config({**defaults, "backend": "rule"}, f"backends file {file}: defaults")
    backends = {}
    for name, entry in entries.items():
        if not isinstance(name, str):  # YAML reads no / on / 1.5 unquoted as bool / number
            raise ConfigError(
                f"backends file {file}: backend name {name!r} is not text (YAML reads "
                f"unquoted true / false / yes / no / on / off and numbers as such): quote it"
            )
        if not isinstance(entry, dict):
            raise ConfigError(f"backends file {file}: backend {name!r} must be a mapping")
        config = _config({**defaults, **entry}, f"backends file {file}: {name}")
        if "backend" not in entry:  # LLMConfig's default would make it the rule stand-in
            raise ConfigError(
                f"backends file {file}: backend {name!r} does not say which backend it is "
                "(backend: openai:<model>, or rule / random for a stand-in)"
            )
        backends[name] = config
    return BackendsFile(str(file), dict(defaults), backends)


def backends_file_from_env(fallback: str | Path | None = None) -> BackendsFile:
    """The file named by ``$SKYVLN_EVAL_BACKENDS_FILE`` (else ``fallback``), or none."""
    path = os.environ.get(BACKENDS_FILE_ENV) or fallback
    return load_backends_file(path) if path else BackendsFile()


def resolve_backend(entry: str, backends: BackendsFile) -> tuple[str, LLMConfig]:
    """A table label and the full configuration of one backend entry (name or spec)."""
    if entry in backends.backends:
        return entry, backends.backends[entry]
    shown = shown_backend(entry)  # the server's credentials or query (refused) left out
    if _SPEC.fullmatch(entry) is None:
        if backends.backends:
            raise UnknownNameError(
                f"backend (in {backends.path})", shown, sorted(backends.backends)
            )
        named = (
            f"the backends file {backends.path} names no backend"
            if backends.path
            else f"no backends file names it (set ${BACKENDS_FILE_ENV})"
        )
        raise ConfigError(
            f"{shown!r} is not 'openai:<model>' or 'openai:<model>@<base_url>', and {named}"
        )
    where = f"backend {shown!r} with the defaults of {backends.path or 'the toolkit'}"
    # The server is the entry's (none: OpenAI's), whatever the defaults say.
    config = _config({**backends.defaults, "backend": entry, "base_url": None}, where)
    label = config.backend.split(":", 1)[1] + (f" @ {config.base_url}" if config.base_url else "")
    return label, config


def environment_backends(
    variable: str | None, backends: BackendsFile
) -> list[tuple[str, LLMConfig]]:
    """Every backend named in the environment variable, resolved (labels, configs)."""
    value = os.environ.get(variable, "") if variable else ""
    out: list[tuple[str, LLMConfig]] = []
    for entry in (e.strip() for e in value.split(",")):
        if not entry:
            continue
        try:
            label, config = resolve_backend(entry, backends)
        except ConfigError as error:
            raise ConfigError(f"${variable}: {error}") from None
        if any(label == seen for seen, _ in out):  # one Table II row, run twice over
            raise ConfigError(f"${variable}: {entry!r} is named twice (as {label!r})")
        out.append((label, config))
    return out
