"""Before any episode runs: can the data give what the agent's sensors and detector need?

A detector states the sensors it needs (the simulated one reads the semantic camera; the
GroundingDINO and VLM detectors read RGB). The semantic camera sees the semantic layers
of synthetic tiles, which real xView imagery does not have. A run that cannot work is
refused at once, with a message naming the detector, the data and the alternatives,
rather than failing in every episode.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from skyvln_eval.agent.config import LLM_AGENTS
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


def preflight(config: RunConfig, data_dir: Path, map_names: Iterable[str]) -> None:
    """Refuse ``config`` if its detector needs a sensor that is off, or the data cannot feed
    a sensor that is on (see the module docstring)."""
    if config.agent.name not in LLM_AGENTS:
        return  # random actions and the oracle do not look
    detector = config.agent.detector
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
