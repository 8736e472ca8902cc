"""Reproduce plans: which systems fill the paper's Table I and Table II, and how to run them.

A plan (YAML, ``configs/reproduce/default.yaml``) names Table I's systems (agent parts,
execution mode, controller) over its splits, Table II's LLM backends on one split, the
control figures and the trajectory figures. :func:`planned_runs` turns it into one
:class:`RunConfig` per (system, split), each with its own resumable run directory; a run
whose settings equal another's (a Table II row that is a Table I system) is run once and
shown under both labels.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from skyvln_eval.agent.config import AgentConfig
from skyvln_eval.avdn.constants import DEFAULT_MAX_ACTION_LEN, EpisodeMode, Split
from skyvln_eval.bounds import MAX_BOOTSTRAP_RESAMPLES, MAX_BOOTSTRAP_SEED
from skyvln_eval.config_model import StrictModel
from skyvln_eval.configs import config_path
from skyvln_eval.control.registry import controller_config
from skyvln_eval.errors import (
    FIELD_PATH_CONTEXT,
    ConfigError,
    SettingsError,
    UnknownNameError,
    describe_validation_error,
)
from skyvln_eval.fileio import read_yaml_mapping
from skyvln_eval.harness.config import (
    MAX_ACTION_LEN,
    CommanderSettings,
    DynamicsSettings,
    ExecutionMode,
    RunConfig,
)
from skyvln_eval.harness.executors import ExecutorKind
from skyvln_eval.harness.preflight import check_keys
from skyvln_eval.llm.backends_file import backends_file_from_env
from skyvln_eval.llm.backends_file import environment_backends as _environment_backends
from skyvln_eval.llm.cache import resolve_cache_path
from skyvln_eval.metrics.aggregate import CiUnit
from skyvln_eval.sensing import SensorConfig

DEFAULT_PLAN = "default"
TableName = Literal["table1", "table2"]


class PlanSystem(StrictModel):
    """One system: its label, execution mode, controller and agent settings."""

    label: str = Field(min_length=1)
    mode: ExecutionMode = "dynamics"
    controller: str = "nmpc"
    controller_settings: dict[str, Any] = Field(
        default_factory=dict,
        description="this system's controller settings over the plan's, e.g. "
        "{max_obstacles: 0} for an MPC that ignores obstacles",
    )
    agent: dict[str, Any] = Field(default_factory=dict)


class PlanDynamicsSettings(DynamicsSettings):
    """A plan's dynamics settings: every flying system's, each with its own controller.

    No ``controller`` here: each system names its own (``nmpc`` when it names none), so a
    plan-wide one would be ignored (an audit: ``dynamics.controller: pid`` flew NMPCs).
    Refused rather than made the systems' default: a second default beside the systems'
    own would make which controller flies a row depend on two places of the file.
    """

    @model_validator(mode="before")
    @classmethod
    def _no_controller(cls, data: Any) -> Any:
        if isinstance(data, dict) and "controller" in data:
            raise PydanticCustomError(
                "plan_controller",
                "{problem}",
                {
                    "problem": "a plan sets each system's controller (table1.systems.N."
                    "controller, table2.system.controller; nmpc where none is named), not "
                    "one for all: remove it and name the controller in each system",
                    FIELD_PATH_CONTEXT: "controller",
                },
            )
        return data

    @model_validator(mode="after")
    def _every_obstacle_planned_around(self) -> PlanDynamicsSettings:
        # Replaces the run's check: here it would judge the obstacles against a controller
        # no system flies (the unused default nmpc). Each system's run settings, its
        # controller with these, are checked when the plan loads (ReproducePlan).
        return self


class Table1Plan(StrictModel):
    splits: tuple[Split, ...] = Field(("val_seen", "val_unseen", "test_unseen"), min_length=1)
    systems: tuple[PlanSystem, ...]

    @field_validator("splits")
    @classmethod
    def _each_split_once(cls, splits: tuple[Split, ...]) -> tuple[Split, ...]:
        # Else reported as a row label given twice, which it is not (an audit).
        twice = sorted({s for s in splits if splits.count(s) > 1})
        if twice:
            raise ValueError(f"split(s) {', '.join(twice)} listed more than once")
        return splits


class BackendPlan(StrictModel):
    label: str = Field(min_length=1)
    llm: dict[str, Any]


class Table2Plan(StrictModel):
    """Table II: one system with each backend (listed, and named in the environment
    variable; ``backends_file`` resolves names there, as ``$SKYVLN_EVAL_BACKENDS_FILE``)."""

    split: Split = "test_unseen"
    system: PlanSystem
    backends: tuple[BackendPlan, ...]
    environment_variable: str | None = "SKYVLN_EVAL_BACKENDS"
    backends_file: str | None = None


#: The paper's control figures' cases (:data:`skyvln_eval.control.recordings.PAPER_CASES`).
PaperCase = Literal["static", "dynamic"]


class ControlFiguresPlan(StrictModel):
    controllers: tuple[str, ...] = ("pid", "nmpc")
    cases: tuple[PaperCase, ...] = ("static", "dynamic")

    @field_validator("controllers")
    @classmethod
    def _known_controllers(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        # Checked on load (no solver is built): a misspelt one failed after every run,
        # naming neither the file nor the field.
        for i, name in enumerate(names):
            try:
                controller_config(name)
            except UnknownNameError as error:
                raise PydanticCustomError(
                    "controller", "{problem}", {"problem": str(error), FIELD_PATH_CONTEXT: str(i)}
                ) from None
        return names


class ReproducePlan(StrictModel):
    """Everything ``skyvln-eval reproduce`` runs and writes."""

    name: str = "default"
    data: str = "sample"
    episode_mode: EpisodeMode = "andh"
    # Bounded as score's --seed and --resamples: the plan's bootstrap is score's, and out of
    # bounds it failed with a traceback after every run had flown.
    seed: int = Field(default=0, ge=0, le=MAX_BOOTSTRAP_SEED)
    max_action_len: int = Field(
        default=DEFAULT_MAX_ACTION_LEN,
        ge=1,
        le=MAX_ACTION_LEN,  # a run's bounds: out of them, every planned run was refused
        description="views per dialog round flown, the start included (ANDH-Full: each round)",
    )
    limit: int | None = Field(default=None, ge=1, description="episodes per split (quick plans)")
    resamples: int = Field(default=1000, ge=0, le=MAX_BOOTSTRAP_RESAMPLES)
    ci_unit: CiUnit = Field(
        default="trajectory", description="what intervals resample: trajectories or episodes"
    )
    sensors: SensorConfig = SensorConfig()
    commander: CommanderSettings = CommanderSettings()
    dynamics: PlanDynamicsSettings = PlanDynamicsSettings()
    table1: Table1Plan
    table2: Table2Plan
    control_figures: ControlFiguresPlan = ControlFiguresPlan()
    trajectory_figures: int = Field(default=2, ge=0)
    recordings: int = Field(
        default=2, ge=0, description="example episodes per system saved as Rerun recordings"
    )
    observations_in_logs: bool = Field(
        default=True,
        description="images in the run MCAPs (the default plan: about 610 MB with, 265 without)",
    )

    @model_validator(mode="after")
    def _valid_controllers(self) -> ReproducePlan:
        # Each system's controller gets the plan's controller settings under its own: both
        # are checked here, on load, against that controller (no solver is built).
        systems = [(f"table1.systems.{i}", s) for i, s in enumerate(self.table1.systems)]
        for where, system in [*systems, ("table2.system", self.table2.system)]:
            settings = {**self.dynamics.controller_settings, **system.controller_settings}
            try:
                controller_config(system.controller, settings)
            except UnknownNameError as error:
                field, problem = f"{where}.controller", str(error)
            except SettingsError as error:
                first = error.field.split(".")[0]
                own = first in system.controller_settings or (
                    not first and bool(system.controller_settings)
                )
                field = f"{where}.controller_settings" if own else "dynamics.controller_settings"
                field = ".".join(part for part in (field, error.field) if part)
                problem = error.problem
                if not own:
                    problem += (
                        "; the plan's controller settings go to every system's controller, "
                        f"and system {system.label!r} flies {system.controller}"
                    )
            else:
                continue
            raise PydanticCustomError(
                "controller", "{problem}", {"problem": problem, FIELD_PATH_CONTEXT: field}
            )
        return self

    @model_validator(mode="after")
    def _valid_agents(self) -> ReproducePlan:
        # Each system's agent (and each listed backend with Table II's agent) is checked on
        # load, naming its place in the plan, before any output folder is made.
        checks = [(f"table1.systems.{i}.agent", s.agent) for i, s in enumerate(self.table1.systems)]
        checks.append(("table2.system.agent", self.table2.system.agent))
        for i, backend in enumerate(self.table2.backends):
            llm = {**dict(self.table2.system.agent.get("llm") or {}), **backend.llm}
            checks.append((f"table2.backends.{i}", {**self.table2.system.agent, "llm": llm}))
        for where, agent in checks:
            try:
                AgentConfig.model_validate(agent)
            except ValidationError as error:
                first = error.errors()[0]
                inside, _, problem = describe_validation_error([first], AgentConfig).partition(": ")
                if where.startswith("table2.backends") and not inside.startswith("llm"):
                    where = "table2.system.agent"  # the backend's agent is Table II's
                raise PydanticCustomError(
                    "agent",
                    "{problem}",
                    {"problem": problem, FIELD_PATH_CONTEXT: f"{where}.{inside}"},
                ) from None
        return self

    @model_validator(mode="after")
    def _valid_runs(self) -> ReproducePlan:
        # Each system's run, made as planned_runs makes it, is validated on load: the
        # plan's dynamics with the system's controller are checked together (obstacles
        # beyond its max_obstacles), and against a run's bounds. Unchecked, an invalid run
        # was a traceback when reproduce made it, leaving an empty output folder.
        where = [f"table1.systems.{i}" for i in range(len(self.table1.systems))]
        systems = [*self.table1.systems, self.table2.system]
        first = self.table1.splits[0] if self.table1.splits else self.table2.split
        splits = [*[first] * len(self.table1.systems), self.table2.split]
        for place, system, split in zip([*where, "table2.system"], systems, splits, strict=True):
            try:
                run_config(self, system, system.label, system.agent, split)
            except ConfigError as error:
                raise PydanticCustomError(
                    "run", "{problem}", {"problem": str(error), FIELD_PATH_CONTEXT: place}
                ) from None
        return self


def load_plan(name_or_path: str | Path = DEFAULT_PLAN, **overrides: Any) -> ReproducePlan:
    """A shipped plan by name (``default``) or a plan file; errors name the file and field."""
    path = Path(name_or_path)
    if not path.suffix:
        path = config_path("reproduce", f"{name_or_path}.yaml")
        if not path.is_file():
            raise UnknownNameError("plan", str(name_or_path), shipped_plans())
    data = read_yaml_mapping(path, "reproduce plan")
    data |= {k: v for k, v in overrides.items() if v is not None}
    try:
        return ReproducePlan.model_validate(data)
    except ValidationError as error:
        problems = describe_validation_error(error, ReproducePlan)
        raise ConfigError(f"reproduce plan {path}: {problems}") from None


def shipped_plans() -> list[str]:
    """The names of the plans that come with the toolkit (``default``, ...)."""
    return sorted(p.stem for p in config_path("reproduce").iterdir() if p.suffix == ".yaml")


def environment_backends(
    variable: str | None, backends_file: str | None = None
) -> list[BackendPlan]:
    """Backends named in an environment variable (``openai:<model>[@<base_url>]`` or the
    name of an entry of the backends file), each with its full configuration."""
    resolved = _environment_backends(variable, backends_file_from_env(backends_file))
    return [
        # What the entry (and the file's defaults) set, defaults included, as a plan that
        # lists the backend gives it: left out, a value equal to the default gave way to
        # the plan system's own.
        BackendPlan(label=label, llm=config.model_dump(exclude_unset=True))
        for label, config in resolved
    ]


def slug(text: str) -> str:
    """A file-system-safe name for a label (``"w/o HSD"`` -> ``"w-o-hsd"``)."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "system"


@dataclass(frozen=True)
class PlannedRun:
    """One run of the plan and the table rows it fills (``labels``)."""

    config: RunConfig
    run_dir: Path
    rows: tuple[tuple[TableName, str], ...]


def _kept_answers(llm: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """``llm`` with its response cache in the output folder: a remote model's answers are
    kept, so a resumed or repeated run does not pay for them again (the cache key starts
    with the model and server), a replay reads them from there, and a plan's relative
    ``cache_path`` is taken inside ``--out``, with everything else the plan writes, not in
    the working directory."""
    cache = llm.get("cache_path")
    if cache:
        return {**llm, "cache_path": resolve_cache_path(str(cache), out_dir)}
    if str(llm.get("backend", "")).startswith(("openai:", "replay:")):
        return {**llm, "cache_path": str(out_dir / "llm-cache.sqlite")}
    return llm


def _agent(system: PlanSystem, out_dir: Path, llm: dict[str, Any] | None = None) -> AgentConfig:
    data = dict(system.agent)
    if llm is not None:
        data["llm"] = {**dict(data.get("llm") or {}), **llm}
    if data.get("llm"):
        data["llm"] = _kept_answers(dict(data["llm"]), out_dir)
    try:
        return AgentConfig.model_validate(data)
    except ValidationError as error:
        problems = describe_validation_error(error, AgentConfig)
        raise ConfigError(f"system {system.label!r}: agent settings: {problems}") from None


def planned_runs(
    plan: ReproducePlan,
    out_dir: Path,
    workers: int,
    executor: ExecutorKind,
    data: str | None = None,
) -> list[PlannedRun]:
    """One run per (system, split), deduplicated by settings (labels excluded)."""
    wanted: list[tuple[TableName, str, PlanSystem, AgentConfig, Split, Path]] = []
    in_plan = f"reproduce plan {plan.name!r}"
    for system in plan.table1.systems:
        agent = _agent(system, out_dir)
        # Before any run: a missing key stopped the first run that called the model, after
        # the runs before it.
        check_keys(agent, f"{in_plan}: system {system.label!r}")
        for split in plan.table1.splits:
            run_dir = out_dir / "runs" / slug(system.label) / split
            wanted.append(("table1", system.label, system, agent, split, run_dir))
    variable = plan.table2.environment_variable
    from_environment = environment_backends(variable, plan.table2.backends_file)
    sources = [in_plan] * len(plan.table2.backends) + [f"${variable}"] * len(from_environment)
    for backend, source in zip((*plan.table2.backends, *from_environment), sources, strict=True):
        run_dir = out_dir / "runs" / "backends" / slug(backend.label) / plan.table2.split
        agent = _agent(plan.table2.system, out_dir, dict(backend.llm))
        check_keys(agent, f"{source}: backend {backend.label!r}")
        wanted.append(
            ("table2", backend.label, plan.table2.system, agent, plan.table2.split, run_dir)
        )
    _check_distinct_rows(wanted, out_dir, in_plan)
    runs: dict[str, PlannedRun] = {}
    for table, label, system, agent, split, run_dir in wanted:
        try:
            config = run_config(plan, system, label, agent, split, data, workers, executor)
        except ConfigError as error:  # the plan was checked on load: a --data-dir, --workers
            raise ConfigError(f"{in_plan}: {error}") from None
        key = results_digest(config)
        if key in runs:
            existing = runs[key]
            runs[key] = PlannedRun(
                existing.config, existing.run_dir, (*existing.rows, (table, label))
            )
        else:
            runs[key] = PlannedRun(config, run_dir, ((table, label),))
    return list(runs.values())


def run_config(
    plan: ReproducePlan,
    system: PlanSystem,
    label: str,
    agent: AgentConfig | dict[str, Any],
    split: Split,
    data: str | None = None,
    workers: int | None = None,
    executor: ExecutorKind | None = None,
) -> RunConfig:
    """The settings of ``system``'s run on ``split``, labelled ``label``: the plan's with
    the system's mode, agent and controller; a :class:`ConfigError` naming the system
    (and, in dynamics mode, its controller) when they make no valid run."""
    how = {"workers": workers, "executor": executor}
    try:
        return RunConfig.model_validate(
            {
                "system": label,
                "data": data or plan.data,
                "splits": (split,),
                "episode_mode": plan.episode_mode,
                "limit": plan.limit,
                "mode": system.mode,
                "agent": agent,
                "sensors": plan.sensors,
                "commander": plan.commander,
                "dynamics": _run_dynamics(plan, system),
                "max_action_len": plan.max_action_len,
                "seed": plan.seed,
                "observations_in_logs": plan.observations_in_logs,
                **{k: v for k, v in how.items() if v is not None},
            }
        )
    except ValidationError as error:
        flies = f" flying {system.controller}" if system.mode == "dynamics" else ""
        raise ConfigError(
            f"system {label!r}{flies} with the plan's settings: "
            f"{describe_validation_error(error, RunConfig)}"
        ) from None


def _run_dynamics(plan: ReproducePlan, system: PlanSystem) -> dict[str, Any] | DynamicsSettings:
    """A system's dynamics settings: the plan's with its controller and settings, as a
    mapping that the run validates whole (a copy of the plan's settings was never checked
    with the system's controller). An official-mode system flies nothing: it gets the
    defaults, which it neither records nor digests, and the plan's obstacles are not
    judged against a controller it never builds."""
    if system.mode == "official":
        return DynamicsSettings()
    return {
        **plan.dynamics.model_dump(),
        "controller": system.controller,
        "controller_settings": {
            **plan.dynamics.controller_settings,
            **system.controller_settings,
        },
    }


def _check_distinct_rows(
    wanted: Sequence[tuple[TableName, str, PlanSystem, AgentConfig, Split, Path]],
    out_dir: Path,
    in_plan: str,
) -> None:
    """Refuse two rows of a table that would share a run folder (the same label twice, or
    labels alike once made folder names): they would run into one directory at once, and
    their scores would be one system's twice."""
    first: dict[Path, tuple[TableName, str]] = {}
    for table, label, _, _, _, run_dir in wanted:
        if run_dir not in first:
            first[run_dir] = (table, label)
            continue
        earlier = first[run_dir]
        where = run_dir.relative_to(out_dir)
        same = "the same label twice" if earlier[1] == label else "labels alike as folder names"
        raise ConfigError(
            f"{in_plan}: {earlier[0]} row {earlier[1]!r} and {table} row {label!r} would share "
            f"the run folder {where} ({same}): give each row a label of its own"
        )


def results_digest(config: RunConfig) -> str:
    """The settings that decide a run's results, without its label."""
    return config.model_copy(update={"system": "-"}).digest()
