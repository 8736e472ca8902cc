"""One typed configuration per run, loaded from YAML and validated with errors naming the field.

A run is one system (agent parts, LLM backend, execution mode, controller, obstacle
scenario) on one dataset's splits. ``configs/runs/*.yaml`` holds examples; the reproduce
plan (:mod:`.plan`) lists several of them. The resolved configuration is written into
the run directory, so every table row can be traced to the settings that made it.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Collection
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import yaml
from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError

from skyvln_eval.agent.config import AGENTS, AgentConfig
from skyvln_eval.avdn.constants import DEFAULT_MAX_ACTION_LEN, EpisodeMode, Split
from skyvln_eval.bounds import MAX_THREADS_PER_WORKER, MAX_WORKERS
from skyvln_eval.config_model import StrictModel
from skyvln_eval.control.registry import controller_config, controller_names, make_controller
from skyvln_eval.errors import (
    FIELD_PATH_CONTEXT,
    ConfigError,
    SettingsError,
    UnknownNameError,
    describe_validation_error,
)
from skyvln_eval.fileio import read_yaml_mapping
from skyvln_eval.harness.executors import ExecutorKind
from skyvln_eval.sensing import SensorConfig
from skyvln_eval.sim.plant import PlantConfig, SensorNoise, WindConfig
from skyvln_eval.sim.quadrotor import InputLimits
from skyvln_eval.sim.scenarios import ScenarioKind

ExecutionMode = Literal["official", "dynamics"]


class ObstacleSettings(StrictModel):
    """Obstacles met on every flown segment (dynamics mode), placed against its reference."""

    kind: ScenarioKind = "crossing"
    n_obstacles: int = Field(default=2, ge=0, le=8)
    # At most 10 m each: the scenarios meet the route in a segment's cruise part, and a
    # wider sphere can hold the segment's start or target (an audit's 30 m one held the
    # drone at t = 0: a crash charged to the controller, its tracking "perfect").
    radius_m: float = Field(
        default=1.0, gt=0.0, le=10.0, description="r_obs: another drone, a bird flock"
    )
    safety_radius_m: float = Field(
        default=0.5, ge=0.0, le=10.0, description="r_s added by the controller"
    )
    obstacle_speed_m_s: float = Field(default=1.0, gt=0.0)


class CommanderSettings(StrictModel):
    """The simulated commander that answers the agent's clarification questions from the
    ground truth (:mod:`skyvln_eval.harness.commander`); ``max_questions: 0`` turns it off."""

    max_questions: int = Field(default=2, ge=0, le=20, description="answers per episode")


#: The strongest mean wind or gust a plant takes, m/s (a category 5 hurricane's is 70).
MAX_WIND_M_S: Final = 100.0
#: One axis (east, north, up) of the mean wind, m/s.
_WindAxis = Annotated[float, Field(ge=-MAX_WIND_M_S, le=MAX_WIND_M_S)]


class PlantSettings(StrictModel):
    """What the simulated drone adds to the controller's model (dynamics mode).

    All zero by default: the nominal plant, the controller's own equations integrated more
    finely, with exact state feedback, so the closed loop shows the best case. Wind (a
    mean and a seeded gust) and sensor noise make the model mismatch a real flight has.
    The noise is the controller's state feedback's; the agent's pose (its odometry, an
    AVDN agent's view centre) stays the flown one.
    """

    # Bounds far past any flyable case (a hurricane's wind, noise of a lost sensor): a
    # wind of 1e200 m/s was an episode error naming only numpy's "Maximum allowed size".
    wind_mean_m_s: tuple[_WindAxis, _WindAxis, _WindAxis] = (0.0, 0.0, 0.0)
    gust_std_m_s: float = Field(default=0.0, ge=0.0, le=MAX_WIND_M_S)
    position_noise_std_m: float = Field(default=0.0, ge=0.0, le=1000.0)
    velocity_noise_std_m_s: float = Field(default=0.0, ge=0.0, le=MAX_WIND_M_S)
    attitude_noise_std_rad: float = Field(default=0.0, ge=0.0, le=math.pi)

    @property
    def nominal(self) -> bool:
        return self == PlantSettings()  # every field its zero default

    def plant_config(self) -> PlantConfig:
        return PlantConfig(
            wind=WindConfig(mean_m_s=self.wind_mean_m_s, gust_std_m_s=self.gust_std_m_s),
            noise=SensorNoise(
                position_std_m=self.position_noise_std_m,
                velocity_std_m_s=self.velocity_noise_std_m_s,
                attitude_std_rad=self.attitude_noise_std_rad,
            ),
        )

    def describe(self) -> str:
        """The plant in words, for the tables' captions."""
        if self.nominal:
            return "nominal plant (the controller's model, no wind, exact state)"
        # Its speed in 3-D: a vertical wind is wind too (it was said "wind 0 m/s").
        wind = math.hypot(*self.wind_mean_m_s)
        return (
            f"plant with wind {wind:g} m/s (gusts {self.gust_std_m_s:g} m/s) and feedback noise "
            f"{self.position_noise_std_m:g} m, {self.velocity_noise_std_m_s:g} m/s, "
            f"{self.attitude_noise_std_rad:g} rad"
        )


class DynamicsSettings(StrictModel):
    """How actions are flown in dynamics mode: controller, reference, arrival, obstacles,
    and what the plant adds to the controller's model (``plant``: nominal by default)."""

    controller: str = "nmpc"
    controller_settings: dict[str, Any] = Field(default_factory=dict)
    cruise_speed_m_s: float = Field(default=12.0, gt=0.0)
    max_acceleration_m_s2: float = Field(default=3.5, gt=0.0)
    yaw_rate_max_rad_s: float = Field(default=1.0, gt=0.0)
    arrival_tolerance_m: float = Field(default=2.0, gt=0.0)
    arrival_speed_m_s: float = Field(default=1.0, gt=0.0)
    arrival_yaw_rad: float = Field(default=0.2, gt=0.0)
    max_segment_time_s: float = Field(default=90.0, gt=0.0, description="per action, simulated")
    obstacles: ObstacleSettings = ObstacleSettings()
    end_on_collision: bool = Field(
        default=True, description="a collision ends the episode where it happened (a crash)"
    )
    plant: PlantSettings = PlantSettings()

    @field_validator("controller")
    @classmethod
    def _known_controller(cls, name: str) -> str:
        # Checked on load, before any episode runs (every episode would fail on it). The
        # registry's own lookup decides, aliases included; it raises on an unknown name
        # before building anything.
        if name not in controller_names():
            try:
                make_controller(name)
            except UnknownNameError as error:
                raise ValueError(str(error)) from None
        return name

    @model_validator(mode="after")
    def _every_obstacle_planned_around(self) -> DynamicsSettings:
        """An MPC plans around its ``max_obstacles`` nearest obstacles: with more on the
        route it would drop some from its plan without a word (0 slots is an MPC that
        ignores obstacles on purpose, and a PID has none)."""
        try:
            slots = getattr(
                controller_config(self.controller, self.controller_settings), "max_obstacles", None
            )
        except (UnknownNameError, SettingsError):
            return self  # said by the controller's own check
        count = self.obstacles.n_obstacles if self.obstacles.kind != "none" else 0
        if isinstance(slots, int) and 0 < slots < count:
            raise ValueError(
                f"controller {self.controller!r} plans around its {slots} nearest obstacles "
                f"(max_obstacles), but each segment has {count} (obstacles.n_obstacles): it "
                f"would drop the others from its plan. Set controller_settings: "
                f"{{max_obstacles: {count}}}, or fewer obstacles"
            )
        return self


#: The most views per dialog round a run flies (AVDN's is 10).
MAX_ACTION_LEN: Final = 100


#: Settings that say how a run runs, not what it computes: no digest covers them, and a
#: run directory may be resumed with others.
HOW_IT_RUNS = frozenset({"workers", "executor", "threads_per_worker", "ray_address", "write_logs"})
#: Which episodes a run flies: a run may grow in place (a larger limit) and stay one run.
SELECTION = frozenset({"limit", "episodes"})


class RunConfig(StrictModel):
    """One run: a system on some splits of a dataset.

    ``system`` labels the run's rows in tables. ``data`` is ``"sample"`` (the bundled
    synthetic sample, built on first use), ``"full"`` (the AVDN-sized synthetic set) or a
    path to an AVDN-format dataset. ``episodes`` restricts the run to these episode ids;
    ``limit`` to the first N episodes of each split (file order).
    """

    system: str = Field(min_length=1)
    data: str = "sample"
    splits: tuple[Split, ...] = ("val_seen", "val_unseen", "test_unseen")
    episode_mode: EpisodeMode = "andh"
    episodes: tuple[str, ...] | None = None
    limit: int | None = Field(default=None, ge=1)
    mode: ExecutionMode = "official"
    agent: AgentConfig = AgentConfig()
    sensors: SensorConfig = SensorConfig()
    commander: CommanderSettings = CommanderSettings()
    dynamics: DynamicsSettings = DynamicsSettings()
    max_action_len: int = Field(
        default=DEFAULT_MAX_ACTION_LEN,
        ge=1,
        le=MAX_ACTION_LEN,
        description="views per dialog round flown, the start included (ANDH-Full: each round)",
    )
    seed: int = 0
    workers: int = Field(default=2, ge=1, le=MAX_WORKERS)
    executor: ExecutorKind = "processes"
    threads_per_worker: int = Field(
        default=1,
        ge=1,
        le=MAX_THREADS_PER_WORKER,
        description="processes executor: episodes in threads per worker",
    )
    ray_address: str | None = None
    write_logs: bool = Field(default=True, description="one run MCAP per episode")
    observations_in_logs: bool = Field(
        default=True,
        description="images in the run MCAPs: the official view and every image the agent's "
        "camera captured (about 0.5 MB per episode; false leaves them out)",
    )

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, agent: AgentConfig) -> AgentConfig:
        if agent.name not in AGENTS:
            raise ValueError(str(UnknownNameError("agent", agent.name, list(AGENTS))))
        return agent

    @model_validator(mode="after")
    def _valid_controller_settings(self) -> RunConfig:
        # Checked on load like the controller's name: every episode would fail on a bad
        # setting. Here, not in DynamicsSettings: a reproduce plan's dynamics settings go to
        # each system's own controller (checked by the plan).
        check_controller_settings(
            self.dynamics.controller,
            self.dynamics.controller_settings,
            "dynamics.controller_settings",
        )
        return self

    @field_validator("episodes", mode="before")
    @classmethod
    def _ids_are_text(cls, ids: Any) -> Any:
        # YAML 1.1 reads an unquoted 9101__6_1 as the number 910161: the id is lost, and
        # "should be a valid string" would not say why.
        numbers = [i for i in ids if isinstance(i, int | float)] if isinstance(ids, list) else []
        if numbers:
            raise ValueError(
                f"episode ids are text, but {numbers[0]!r} is a number: YAML reads an unquoted "
                'id such as 9101__6_1 as the number 910161; quote each id: ["9101__6_1", ...]'
            )
        return ids

    @field_validator("episodes")
    @classmethod
    def _some_episodes(cls, ids: tuple[str, ...] | None) -> tuple[str, ...] | None:
        if ids is not None and not ids:
            raise ValueError("an empty list selects no episode: list some, or leave it out")
        return ids

    @field_validator("splits")
    @classmethod
    def _known_splits(cls, splits: tuple[str, ...]) -> tuple[str, ...]:
        if not splits:
            raise ValueError("at least one split is needed")
        if len(set(splits)) != len(splits):
            raise ValueError("a split is listed twice")
        return splits

    def digest(self) -> str:
        """A short hash of the settings that decide the results (not workers or executor)."""
        return self._hash(self._undeciding())

    def settings_digest(self) -> str:
        """:meth:`digest` without the selection (``limit``, ``episodes``): the same for
        every row of a run that grew in place, different for a row of another config."""
        return self._hash(self._undeciding() | SELECTION)

    def system_digest(self) -> str:
        """:meth:`settings_digest` without the splits and the data too: the same for every
        run of one system, whichever episodes it ran, so that rows a table would pool under
        one system label can be checked to be of one configuration."""
        return self._hash(self._undeciding() | SELECTION | {"splits", "data"})

    def legacy_settings_digest(self) -> str | None:
        """The :meth:`settings_digest` an official-mode run's rows recorded while it
        covered the unused flight settings too (``None`` in dynamics mode, which always
        used them): their rows are this config's all the same."""
        return self._hash(HOW_IT_RUNS | SELECTION) if self._unflown() else None

    def _hash(self, excluded: Collection[str]) -> str:
        text = yaml.safe_dump(self.model_dump(mode="json", exclude=set(excluded)), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    def _unflown(self) -> frozenset[str]:
        """The flight settings of a run that flies nothing (official mode): they decide
        nothing, and recorded with it, they said it flew an NMPC through obstacles."""
        return frozenset({"dynamics"}) if self.mode == "official" else frozenset()

    def _undeciding(self) -> frozenset[str]:
        """What does not decide this run's results: how it runs, and unflown settings."""
        return HOW_IT_RUNS | self._unflown()

    def settings_yaml(self) -> str:
        """The YAML of what :meth:`settings_digest` covers."""
        relevant = self.model_dump(mode="json", exclude=set(self._undeciding() | SELECTION))
        return yaml.safe_dump(relevant, sort_keys=False, allow_unicode=True)

    def to_yaml(self) -> str:
        """The whole config (what a run directory keeps to resume with), without flight
        settings an official-mode run does not use."""
        kept = self.model_dump(mode="json", exclude=set(self._unflown()))
        return yaml.safe_dump(kept, sort_keys=False, allow_unicode=True)


def check_controller_settings(controller: str, settings: dict[str, Any], field: str) -> None:
    """Check ``settings`` against controller ``controller``'s settings (no solver is built);
    in a pydantic validator, a bad one is an error at ``field`` plus its path inside."""
    try:
        config = controller_config(controller, settings)
    except SettingsError as error:
        inside = ".".join(part for part in (field, error.field) if part)
        raise PydanticCustomError(
            "controller_settings",
            "{problem}",
            {"problem": error.problem, FIELD_PATH_CONTEXT: inside},
        ) from None
    beyond = _beyond_the_drone(getattr(config, "limits", None))
    if beyond:
        name, planned, applied = beyond
        raise PydanticCustomError(
            "controller_settings",
            "{problem}",
            {
                "problem": f"{planned!r} goes beyond the simulated drone's {applied!r}: the drone "
                "saturates there, so the controller would plan (and its log claim) commands that "
                "are never applied; use a value within the drone's",
                FIELD_PATH_CONTEXT: f"{field}.limits.{name}",
            },
        )


def _beyond_the_drone(limits: object) -> tuple[str, float, float] | None:
    """The first of ``limits`` wider than the simulated drone's (the harness flies the
    default :class:`PlantConfig`): its name, the controller's value and the drone's."""
    if not isinstance(limits, InputLimits):
        return None
    drone = PlantConfig().limits
    if limits.thrust_min_m_s2 < drone.thrust_min_m_s2:
        return "thrust_min_m_s2", limits.thrust_min_m_s2, drone.thrust_min_m_s2
    for name in ("thrust_max_m_s2", "tilt_ref_max_rad"):
        if getattr(limits, name) > getattr(drone, name):
            return name, getattr(limits, name), getattr(drone, name)
    return None


def run_config_from_mapping(data: Any, source: str) -> RunConfig:
    """Validate a mapping as a run config; errors name ``source`` and the field path."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a run config must be a mapping, got {type(data).__name__}")
    try:
        return RunConfig.model_validate(data)
    except ValidationError as error:
        raise ConfigError(f"{source}: {describe_validation_error(error, RunConfig)}") from None


def load_run_config(path: str | Path, **overrides: Any) -> RunConfig:
    """Read a YAML run config; ``overrides``, the command line's options (``workers=4`` for
    ``--workers 4``), replace top-level fields. A bad value is named where it came from:
    the file and field, or the option (``--executor``)."""
    file = Path(path)
    data = read_yaml_mapping(file, "run config")
    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        return RunConfig.model_validate(data | given)
    except ValidationError as error:
        from_options = [e for e in error.errors() if e["loc"] and e["loc"][0] in given]
        from_file = [e for e in error.errors() if e not in from_options]
        parts = [  # top-level fields: the option and its value say it all
            f"--{str(e['loc'][0]).replace('_', '-')} {given[str(e['loc'][0])]!r}: "
            + str(e["msg"]).removeprefix("Value error, ").rstrip(".")
            for e in from_options
        ]
        if from_file:
            parts.insert(0, f"run config {file}: {describe_validation_error(from_file, RunConfig)}")
        raise ConfigError("; ".join(parts)) from None


__all__ = [
    "CommanderSettings",
    "DynamicsSettings",
    "ExecutionMode",
    "ObstacleSettings",
    "RunConfig",
    "check_controller_settings",
    "load_run_config",
    "run_config_from_mapping",
]
