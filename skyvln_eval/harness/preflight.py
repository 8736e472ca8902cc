"""Before any episode runs: can the data give what the agent's sensors and detector need,
and does the environment hold the API keys of the models the agent calls?

A detector states the sensors it needs (the simulated one reads the semantic camera; the
GroundingDINO and VLM detectors read RGB). The semantic camera sees the semantic layers
of synthetic tiles, which real xView imagery does not have. A run that cannot work is
refused at once, with a message naming the detector, the data and the alternatives,
rather than failing in every episode. So is a run whose model needs an API key that is
not set (OpenAI's server): its first call would stop it, and a reproduction after the
runs before it. So is a run whose model is served on this machine (a loopback address)
when nothing listens there: every call would fail, and the run would end as a column of
"error" cells. A remote server is not probed: it may be down for a moment, and its
failures are recorded as they happen.
"""

from __future__ import annotations

import ipaddress
import socket
import urllib.parse
from collections.abc import Iterable
from pathlib import Path

from skyvln_eval.agent.config import LLM_AGENTS, AgentConfig, DetectorConfig, models_called
from skyvln_eval.errors import ConfigError
from skyvln_eval.harness.config import RunConfig
from skyvln_eval.worlds.layers import has_world_layers

ALTERNATIVES = (
    "on RGB-only imagery use sensors {semantic: false} with detector 'grounding_dino' "
    "(pip install 'skyvln-eval[vision]') or 'vlm' (a vision-language model over the OpenAI "
    "protocol)"
)


class PreflightError(ConfigError):
    """A run that cannot work with its data, sensors and detector: refused before it starts."""


#: How long a local server may take to accept a connection before it counts as absent.
CONNECT_TIMEOUT_S = 2.0


def missing_keys(agent: AgentConfig) -> list[str]:
    """``"field: what to set"`` for each model ``agent`` calls whose API key is not in the
    environment (each backend's own rule: OpenAI's server needs one, a local server not)."""
    found = ((field, llm.missing_key()) for field, llm in models_called(agent).items())
    return [f"{field}: {missing}" for field, missing in found if missing]


def absent_local_servers(agent: AgentConfig) -> list[str]:
    """``"field: what is wrong"`` for each model ``agent`` calls on a loopback address
    where nothing accepts a connection."""
    absent = []
    for field, llm in models_called(agent).items():
        if not llm.backend.startswith("openai:") or not llm.base_url:
            continue  # a stand-in, a replay of the cache, or OpenAI's own server
        url = urllib.parse.urlsplit(llm.base_url)
        if not _is_loopback(url.hostname):
            continue
        port = url.port or (443 if url.scheme == "https" else 80)
        try:
            socket.create_connection((url.hostname, port), CONNECT_TIMEOUT_S).close()
        except OSError as error:
            absent.append(
                f"{field}: nothing answers at {llm.base_url} ({error.strerror or error}); "
                "start the server first (README: 'A real local LLM') or set base_url to "
                "one that runs"
            )
    return absent


def _is_loopback(host: str | None) -> bool:
    if host is None:
        return False
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name: not probed
        return False


def check_keys(agent: AgentConfig, source: str) -> None:
    """Refuse ``agent`` (of ``source``: a run config, a plan's system, an environment
    variable's backend) when a model it calls lacks its API key; the key is never shown."""
    missing = missing_keys(agent)
    if missing:
        raise PreflightError(f"{source}: {'; '.join(missing)}")


def check_local_servers(agent: AgentConfig, source: str) -> None:
    """Refuse ``agent`` (of ``source``) when a model it calls is served on this machine
    where nothing listens (:func:`absent_local_servers`)."""
    absent = absent_local_servers(agent)
    if absent:
        raise PreflightError(f"{source}: {'; '.join(absent)}")


def check_detector_weights(detector: DetectorConfig, source: str) -> None:
    """Refuse a GroundingDINO detector whose weights are not on this machine, or whose
    device torch cannot use, before any episode: else every episode ended in error, each
    trying to load them again (an audit)."""
    from skyvln_eval.agent.grounding_dino import DEFAULT_MODEL, check_weights_present

    try:
        check_weights_present(detector.model or DEFAULT_MODEL)
    except ConfigError as error:
        raise PreflightError(f"{source}: {error}") from None
    try:
        import torch
    except ImportError:
        return  # said by the detector when it is built, with the extra to install
    try:
        device = torch.device(detector.device)
    except RuntimeError as error:
        raise PreflightError(
            f"{source}: detector device {detector.device!r} is not a torch device ({error})"
        ) from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise PreflightError(
            f"{source}: detector device {detector.device!r}: torch has no CUDA here; use 'cpu'"
        )


def preflight(config: RunConfig, data_dir: Path, map_names: Iterable[str]) -> None:
    """Refuse ``config`` if a model its agent calls lacks its API key or is served on this
    machine where nothing listens, its detector needs a sensor that is off, or the data
    cannot feed a sensor that is on (see the module docstring)."""
    check_keys(config.agent, f"run {config.system!r}")
    check_local_servers(config.agent, f"run {config.system!r}")
    if config.agent.name not in LLM_AGENTS:
        return  # random actions and the oracle do not look
    detector = config.agent.detector
    if detector.name == "grounding_dino":
        check_detector_weights(detector, f"run {config.system!r}")
    off = sorted(detector.requires - config.sensors.kinds)
    if off:
        raise PreflightError(
            f"run {config.system!r}: detector {detector.name!r} needs the {', '.join(off)} "
            f"sensor(s), which the run's sensors turn off; turn them on, or {ALTERNATIVES}"
        )
    if "semantic" not in config.sensors.kinds:
        return
    maps = sorted(set(map_names))
    without = [name for name in maps if not has_world_layers(data_dir, name)]
    if without:
        raise PreflightError(
            f"run {config.system!r}: the semantic camera (which detector {detector.name!r} "
            f"reads) needs the semantic layers of synthetic tiles, and data {data_dir} has "
            f"none for {len(without)} of its {len(maps)} map(s) (e.g. {without[0]}; real "
            f"xView imagery is RGB only); {ALTERNATIVES}"
        )
