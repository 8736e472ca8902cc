"""Typed agent configuration, loadable from YAML, and construction of agents by name.

``AgentConfig(name="skyvln", hsd=False)`` is the w/o-HSD ablation, ``tbma=False`` the
w/o-TBMA one; ``name="navgpt"`` and ``"random"`` are the baselines, and ``"ground_truth"``
names the oracle, a labelled reference that the harness builds (:func:`build_agent`
refuses it).
Every part is switchable here, and :meth:`Agent.settings` records the result in the run.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from pydantic import Field, ValidationError, field_validator

from skyvln_eval.agent.base import Agent
from skyvln_eval.agent.detectors import (
    Detector,
    create_detector,
    detector_class,
    known_detectors,
)
from skyvln_eval.agent.perception import Perception, PerceptionConfig
from skyvln_eval.config_model import StrictModel
from skyvln_eval.errors import ConfigError, UnknownNameError, describe_validation_error
from skyvln_eval.fileio import load_yaml
from skyvln_eval.llm.client import LLMClient
from skyvln_eval.llm.config import LLMConfig, build_client
from skyvln_eval.sensing import SensorKind


class DetectorConfig(StrictModel):
    """Which detector, and its settings: imperfections (``simulated``), weights
    (``grounding_dino``) or the vision-language model to ask (``vlm``)."""

    name: str = "simulated"
    miss_rate: float = Field(default=0.1, ge=0.0, le=1.0)
    false_positive_rate: float = Field(
        default=0.03, ge=0.0, le=1.0, description="share of ordinary buildings taken for landmarks"
    )
    confusion_rate: float = Field(default=0.05, ge=0.0, le=1.0, description="wrong labels")
    close_look_m: float = Field(
        default=70.0, ge=0.0, description="phantoms are seen through closer"
    )
    min_pixels: int = Field(default=25, ge=1)
    model: str | None = Field(
        default=None, description="grounding_dino weights (name or local folder)"
    )
    box_threshold: float = Field(default=0.35, ge=0.0, le=1.0)
    text_threshold: float = Field(default=0.25, ge=0.0, le=1.0)
    device: str = Field(default="cpu", description="grounding_dino: torch device")
    threads: int | None = Field(
        default=1, ge=1, le=256, description="grounding_dino: torch threads per worker process"
    )
    llm: LLMConfig | None = Field(default=None, description="vlm: the model that looks")

    @field_validator("name")
    @classmethod
    def _known(cls, name: str) -> str:
        if name not in known_detectors():
            raise UnknownNameError("detector", name, known_detectors())
        return name

    @property
    def requires(self) -> frozenset[SensorKind]:
        """The sensors this detector needs (checked before a run starts)."""
        return detector_class(self.name).requires

    def build(self, seed: int) -> Detector:
        if self.name == "simulated":
            return create_detector(
                "simulated",
                miss_rate=self.miss_rate,
                false_positive_rate=self.false_positive_rate,
                confusion_rate=self.confusion_rate,
                close_look_m=self.close_look_m,
                min_pixels=self.min_pixels,
                seed=seed,
            )
        if self.name == "vlm":
            if self.llm is None:
                raise ConfigError("detector 'vlm' needs llm: the vision-language model to ask")
            return create_detector("vlm", llm=self.llm)
        options: dict[str, Any] = {
            "box_threshold": self.box_threshold,
            "text_threshold": self.text_threshold,
            "device": self.device,
            "threads": self.threads,
        }
        if self.model:
            options["model"] = self.model
        return create_detector(self.name, **options)


class AgentConfig(StrictModel):
    """One agent: its kind (``name``), ablation switches, perception, detector and LLM."""

    name: str = "skyvln"
    hsd: bool = True
    tbma: bool = True
    top_k: int = Field(default=3, ge=1, le=10)
    seed: int = 0
    meet_radius_m: float = Field(default=40.0, gt=0.0)
    perception: PerceptionConfig = PerceptionConfig()
    detector: DetectorConfig = DetectorConfig()
    llm: LLMConfig = LLMConfig()

    @classmethod
    def from_yaml(cls, path: str | Path) -> AgentConfig:
        """Read and validate a YAML agent config; errors name the file and the field."""
        file = Path(path)
        try:
            data = load_yaml(file.read_text(encoding="utf-8"), file) or {}
        except (OSError, yaml.YAMLError) as error:
            raise ConfigError(f"agent config {file}: {error}") from error
        try:
            return cls.model_validate(data)
        except ValidationError as error:
            problems = describe_validation_error(error, cls)
            raise ConfigError(f"agent config {file}: {problems}") from None


def _perception(config: AgentConfig) -> Perception:
    return Perception(config.perception, config.detector.build(config.seed))


def _skyvln(config: AgentConfig, client: LLMClient | None) -> Agent:
    from skyvln_eval.agent.skyvln import SkyVLNAgent

    return SkyVLNAgent(
        client or build_client(config.llm),
        _perception(config),
        config.llm,
        hsd=config.hsd,
        tbma=config.tbma,
        top_k=config.top_k,
        seed=config.seed,
        meet_radius_m=config.meet_radius_m,
    )


def _navgpt(config: AgentConfig, client: LLMClient | None) -> Agent:
    from skyvln_eval.agent.baselines import NavGPTAgent

    return NavGPTAgent(
        client or build_client(config.llm), _perception(config), config.llm, seed=config.seed
    )


def _random(config: AgentConfig, client: LLMClient | None) -> Agent:
    from skyvln_eval.agent.baselines import RandomAgent

    return RandomAgent(seed=config.seed)


def _ground_truth(config: AgentConfig, client: LLMClient | None) -> Agent:
    raise ConfigError(
        "the ground-truth replay reads the route, which no agent may: it is an oracle the "
        "harness builds from the episode (skyvln_eval.harness.oracle.ground_truth_oracle); "
        "runs and plans with agent name 'ground_truth' get it"
    )


#: Agents whose modules call an LLM backend (the others never do).
LLM_AGENTS = frozenset({"skyvln", "navgpt"})


def models_called(agent: AgentConfig) -> dict[str, LLMConfig]:
    """The models ``agent`` calls, by their config field (``agent.llm``, and a VLM
    detector's ``agent.detector.llm``): none for random actions and the oracle."""
    if agent.name not in LLM_AGENTS:
        return {}
    models = {"agent.llm": agent.llm}
    if agent.detector.name == "vlm" and agent.detector.llm is not None:
        models["agent.detector.llm"] = agent.detector.llm
    return models


AGENTS: dict[str, Callable[[AgentConfig, LLMClient | None], Agent]] = {
    "skyvln": _skyvln,
    "navgpt": _navgpt,
    "random": _random,
    "ground_truth": _ground_truth,
}


def build_agent(config: AgentConfig, client: LLMClient | None = None) -> Agent:
    """The agent ``config.name`` describes; ``client`` overrides the one ``config.llm`` builds."""
    if config.name not in AGENTS:
        raise UnknownNameError("agent", config.name, list(AGENTS))
    return AGENTS[config.name](config, client)
