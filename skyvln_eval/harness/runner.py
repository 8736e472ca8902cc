"""Run one episode of a run: the task every executor runs, in whatever process it lands.

:func:`run_episode_task` loads the episode from its episode MCAP, the world of its map,
builds the agent (seeded by the episode, so results depend neither on the order nor on the
worker count), flies the episode in the run's mode, writes the run MCAP (and, with
dynamics, the control log) and returns the episode's :class:`EpisodeResult` with its
status (``ok``, ``degraded`` or ``error``: :func:`~skyvln_eval.metrics.records.judge_status`)
and wall time. Anything the episode raises makes it ``error`` with its traceback; the run
carries on, unless the error says no episode can succeed (refused credentials).

Worlds are cached per process and controllers per thread: loading a map or building a
solver once serves every episode on it, and no two threads ever share a solver (CasADi
solver objects are not thread-safe).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.agent.base import Agent
from skyvln_eval.agent.config import LLM_AGENTS, build_agent
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.avdn.records import Episode
from skyvln_eval.control import Controller, make_controller, save_flight_log
from skyvln_eval.converters.reader import read_episode
from skyvln_eval.errors import stops_the_run
from skyvln_eval.frames import ViewPose
from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.harness.config import RunConfig
from skyvln_eval.harness.control_messages import ns
from skyvln_eval.harness.dynamics_loop import DynamicsRollout, run_dynamics_episode
from skyvln_eval.harness.executors import TASK_FAILURES
from skyvln_eval.harness.llm_caches import caches_in
from skyvln_eval.harness.official_loop import OfficialRollout, run_official_episode
from skyvln_eval.harness.oracle import ground_truth_oracle, is_oracle
from skyvln_eval.harness.rollout import CallsMade
from skyvln_eval.harness.run_log import RunLogContent, Step, named_views, write_run_log
from skyvln_eval.harness.seeds import run_episode_seed
from skyvln_eval.llm_records import LlmCall
from skyvln_eval.metrics.cost import call_totals
from skyvln_eval.metrics.records import EpisodeResult, judge_status
from skyvln_eval.metrics.safety import summarise_control
from skyvln_eval.native_calls import NATIVE_CALLS
from skyvln_eval.worlds.loading import load_world
from skyvln_eval.worlds.tile import WorldTile

LOGS_DIR = "logs"
CONTROL_DIR = "control"
_WORLD_CACHE_SIZE = 3
#: The run log's clock in official mode: one second per step (it has no time of its own).
OFFICIAL_STEP_S = 1.0


@dataclass(frozen=True)
class EpisodeTask:
    """Everything a worker needs for one episode (small and picklable). ``fresh_answers``:
    the episode is run again after an error (``--retry-failed``), so its LLM calls go to
    the endpoint, not to the response cache, which would give the unusable answers back."""

    config_json: str
    data_dir: str
    run_dir: str
    split: str
    episode_id: str
    episode_log: str
    fresh_answers: bool = False


@functools.lru_cache(maxsize=4)
def _config(config_json: str) -> RunConfig:
    return RunConfig.model_validate_json(config_json)


@functools.lru_cache(maxsize=4)
def _config_texts(config_json: str) -> tuple[str, str]:
    """The digest and YAML of what decides an episode's result (made once per run): the
    config without how it runs (workers, executor) and without the selection (``limit``,
    ``episodes``), so an episode's row and log are the same whichever executor ran it and
    however the run grew."""
    config = _config(config_json)
    return config.settings_digest(), config.settings_yaml()


@functools.lru_cache(maxsize=4)
def _system_digest(config_json: str) -> str:
    """:meth:`RunConfig.system_digest`, made once per run, not once per episode."""
    return _config(config_json).system_digest()


def config_marks(config: RunConfig, config_json: str) -> dict[str, Any]:
    """What a row records of the config that made it: a resume and ``score`` refuse a row
    whose marks are not the run's (:func:`~skyvln_eval.harness.run.foreign_rows`)."""
    return {
        "settings_digest": _config_texts(config_json)[0],
        "system_digest": _system_digest(config_json),
        "execution_mode": config.mode,
    }


_worlds: OrderedDict[tuple[str, str], WorldTile] = OrderedDict()
_worlds_guard = threading.Lock()
_world_loading: dict[tuple[str, str], threading.Lock] = {}


def _world(data_dir: str, map_name: str, georef: MapGeoref) -> WorldTile:
    """The map's world, loaded once per process: episodes that start together in threads
    wait for the one that loads it rather than each loading it again."""
    key = (data_dir, map_name)
    with _worlds_guard:
        loading = _world_loading.setdefault(key, threading.Lock())
    with loading:
        with _worlds_guard:
            if key in _worlds:
                _worlds.move_to_end(key)
                return _worlds[key]
        world = load_world(data_dir, map_name, georef)
        with _worlds_guard:
            _worlds[key] = world
            while len(_worlds) > _WORLD_CACHE_SIZE:
                _worlds.popitem(last=False)
    return world


_thread_controllers = threading.local()


def _controller(name: str, settings_json: str) -> Controller:
    """This thread's controller for these settings (built on first use)."""
    cache: dict[tuple[str, str], Controller] = _thread_controllers.__dict__.setdefault("by_key", {})
    key = (name, settings_json)
    if key not in cache:
        with NATIVE_CALLS:  # CasADi's symbolic core is not thread-safe either
            cache[key] = make_controller(name, json.loads(settings_json))
    return cache[key]


def _agent(config: RunConfig, episode: Episode, seed: int, run_dir: str) -> Agent:
    """The run's agent for ``episode``, its relative response cache paths taken inside
    ``run_dir``; the ground-truth replay is an oracle the harness builds from the episode
    (no agent is given the route)."""
    if is_oracle(config.agent.name):
        return ground_truth_oracle(episode)
    return build_agent(caches_in(config.agent.model_copy(update={"seed": seed}), run_dir))


def log_path(run_dir: str | Path, split: str, episode_id: str) -> Path:
    return Path(run_dir) / LOGS_DIR / split / f"{episode_id}.mcap"


def control_log_name(split: str, episode_id: str) -> str:
    """Where an episode's control log lives, relative to the run directory."""
    return f"{CONTROL_DIR}/{split}/{episode_id}.parquet"


def _steps(
    rollout: OfficialRollout | DynamicsRollout,
    times_s: list[float],
    targets: Sequence[ViewPose] = (),
) -> list[Step]:
    """The run log's steps: one per decision, with its action's target pose when flown."""
    return [
        Step(
            t_s=times_s[k],
            step_index=k,
            view=rollout.views[min(k, len(rollout.views) - 1)],
            thought=rollout.thoughts[k],
            action=action,
            feedback=rollout.feedbacks[k],
            trace=rollout.traces[k],
            target=targets[k] if k < len(targets) else None,
            camera_views=named_views(
                rollout.traces[k], rollout.captures[k] if k < len(rollout.captures) else []
            ),
        )
        for k, action in enumerate(rollout.actions)
    ]


def _commander(
    config: RunConfig, episode: Episode, world: WorldTile, seed: int
) -> SimulatedCommander | None:
    if config.commander.max_questions == 0 or config.agent.name not in LLM_AGENTS:
        return None
    return SimulatedCommander(episode, world, config.commander.max_questions, seed)


def _official(
    agent: Agent, episode: Episode, world: WorldTile, config: RunConfig, seed: int
) -> tuple[OfficialRollout, RunLogContent, dict[str, Any]]:
    commander = _commander(config, episode, world, seed)
    rollout = run_official_episode(
        agent, episode, world, episode.view_budget(config.max_action_len), config.sensors, commander
    )
    times = [k * OFFICIAL_STEP_S for k in range(len(rollout.views))]
    content = RunLogContent(
        _steps(rollout, times), rollout.views, times, clock_step_ns=ns(OFFICIAL_STEP_S)
    )
    extra = {
        "step_outcomes": list(rollout.step_outcomes),
        "simulated_s": (len(rollout.views) - 1) * OFFICIAL_STEP_S,
    }
    return rollout, content, extra


def _dynamics(
    agent: Agent, episode: Episode, world: WorldTile, config: RunConfig, seed: int
) -> tuple[DynamicsRollout, RunLogContent, dict[str, Any], dict[str, Any]]:
    """The flown episode, its run log's content, its result's extras, and what its control
    log keeps of how it was flown (the controller's settings as built: its horizon, limits,
    whether compiled and which QP solver ran; the flight's: speeds, scenario)."""
    settings = config.dynamics
    controller = _controller(
        settings.controller, json.dumps(settings.controller_settings, sort_keys=True)
    )
    flown_with = {
        "controller": settings.controller,
        "controller_settings": controller.settings(),
        "flight": settings.model_dump(mode="json", exclude={"controller_settings"}),
    }
    rollout = run_dynamics_episode(
        agent,
        episode,
        world,
        controller,
        settings,
        seed,
        episode.view_budget(config.max_action_len),
        config.sensors,
        _commander(config, episode, world, seed),
    )
    view_times = [0.0, *rollout.segment_end_times_s][: len(rollout.views)]
    content = RunLogContent(
        _steps(rollout, rollout.decision_times_s, rollout.targets),
        rollout.views,
        view_times,
        rollout.control_log,
        rollout.obstacle_segments,
    )
    extra: dict[str, Any] = {
        "simulated_s": rollout.simulated_s,
        "segments_reached": [bool(r) for r in rollout.reached],
    }
    return rollout, content, extra, flown_with


def llm_backend(config: RunConfig) -> str | None:
    """The backend that answered the agent's LLM calls (``rule``, ``openai:gpt-4o``, ...),
    recorded in every result so that a table can tell a stand-in from a model; ``None``
    for an agent without LLM modules. A server sent the task data is marked (``task-data:
    openai:gpt-4o``): what answered may be a stand-in reading it, not the model named."""
    return config.agent.llm.answered_by if config.agent.name in LLM_AGENTS else None


def detector_name(config: RunConfig) -> str | None:
    """The detector that found the agent's landmarks (``simulated``, ``grounding_dino``,
    ``vlm``), recorded in every result so that a table can say which rows read the
    simulator's landmark segmentation rather than pixels; ``None`` for an agent that does
    not perceive (the perceiving agents are the LLM agents). GroundingDINO is named with
    its weights (``grounding_dino:IDEA-Research/grounding-dino-tiny``): a table says
    which model found a row's landmarks."""
    if config.agent.name not in LLM_AGENTS:
        return None
    detector = config.agent.detector
    if detector.name == "grounding_dino":
        from skyvln_eval.agent.grounding_dino import DEFAULT_MODEL

        return f"grounding_dino:{detector.model or DEFAULT_MODEL}"
    return detector.name


def run_episode_task(task: EpisodeTask) -> EpisodeResult:
    """Run one episode; never raises for the episode's own failures (see the module docstring)."""
    config = _config(task.config_json)
    digest, config_yaml = _config_texts(task.config_json)
    episode: Episode | None = None
    made: CallsMade | None = None
    started = time.perf_counter()
    try:
        episode = read_episode(task.episode_log)
        if episode.episode_id != task.episode_id or episode.split != task.split:
            raise ValueError(
                f"{task.episode_log} holds {episode.split}/{episode.episode_id}, "
                f"expected {task.split}/{task.episode_id}"
            )
        world = _world(task.data_dir, episode.map_name, episode.georef)
        seed = run_episode_seed(config.seed, task.split, task.episode_id)
        agent = _agent(config, episode, seed, task.run_dir)
        if task.fresh_answers:
            for client in agent.llm_clients():
                client.read_cache = False
        made = CallsMade(agent)  # if the episode raises, its calls still count
        control = control_log = None
        rollout: OfficialRollout | DynamicsRollout
        if config.mode == "official":
            rollout, content, extra = _official(agent, episode, world, config, seed)
        else:
            flown, content, extra, flown_with = _dynamics(agent, episode, world, config, seed)
            rollout = flown
            if len(flown.control_log):
                control_log = control_log_name(task.split, task.episode_id)
                save_flight_log(
                    flown.control_log.assign(episode_id=task.episode_id),
                    Path(task.run_dir) / control_log,
                    flown_with,
                )
                # The settings by argument, not in the frame's attrs: pandas deep-copies
                # attrs at every column read (7% of a dynamics run's time).
                control = summarise_control(flown.control_log, control_log, flown_with)
        solve_failures = 0 if control is None else control.solve_failures
        status, error = judge_status(
            rollout.llm_calls, rollout.failures, rollout.error, solve_failures, len(rollout.actions)
        )
        extra |= {
            "stop_reason": rollout.stop_reason,
            "actions": len(rollout.actions),
            # Its view budget is max_action_len per round flown (AVDN's: 10 per round).
            "rounds_flown": episode.rounds_flown,
            "seed": seed,
            **config_marks(config, task.config_json),
            "oracle": is_oracle(config.agent.name),
            "llm_backend": llm_backend(config),
            "detector": detector_name(config),
            "questions": rollout.questions,
        }
        if config.write_logs:
            run_metadata = {
                "system": config.system,
                "split": task.split,
                "execution_mode": config.mode,
                "config": config_yaml,
                "config_digest": digest,
                "seed": str(seed),
                "stop_reason": rollout.stop_reason,
                "status": status,
                "error": error or "",
                # What explains a degraded or error status, for the viewer's episode card.
                **_status_counts(rollout),
            }
            write_run_log(
                log_path(task.run_dir, task.split, task.episode_id),
                episode,
                world,
                dataclasses.replace(content, run_metadata=run_metadata),
                config.observations_in_logs,
            )
        return EpisodeResult(
            episode_id=task.episode_id,
            split=task.split,
            mode=config.episode_mode,
            system=config.system,
            status=status,
            visited_views=np.stack(rollout.views),
            gt_path_corners=ground_truth(episode),
            error=error,
            control=control,
            control_log=control_log,
            llm_calls=tuple(rollout.llm_calls),
            decisions=len(rollout.actions),
            module_failures=tuple(rollout.failures),
            extra=extra | {"wall_s": round(time.perf_counter() - started, 6)},
        )
    except TASK_FAILURES as exc:  # the episode failed: record it and let the run go on
        episode = episode or read_episode(task.episode_log)
        error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
        fatal = stops_the_run(exc)
        calls = () if made is None else tuple(made.since())
        wall_s = time.perf_counter() - started
        return failed_result(config, task, episode, error, wall_s, fatal, calls)


def _status_counts(rollout: OfficialRollout | DynamicsRollout) -> dict[str, str]:
    """The LLM call and fallback counts behind an episode's status, as run log metadata."""
    totals = call_totals(rollout.llm_calls, rollout.failures, len(rollout.actions))
    keys = ("llm_calls", "llm_failed_calls", "llm_parse_failures", "fallback_decisions")
    return {key: str(int(totals[key])) for key in (*keys, "module_failures")}


def ground_truth(episode: Episode) -> NDArray[np.float64]:
    """The route a result is scored against: the episode's, or its start view alone when
    the ground truth is withheld (the real AVDN test_unseen; a multi-round episode would
    otherwise concatenate each round's start into something that looks like a route)."""
    corners = episode.gt_path_corners
    return corners if episode.has_ground_truth else corners[:1]


def failed_result(
    config: RunConfig,
    task: EpisodeTask,
    episode: Episode,
    error: str,
    wall_s: float | None = None,
    fatal: str | None = None,
    llm_calls: tuple[LlmCall, ...] = (),
) -> EpisodeResult:
    """The row of an episode that raised: no views, its ground truth (so that it counts in
    every score as a failure, never dropped), the error with its traceback and the LLM
    calls it made (their cost and tokens count; see :class:`~.rollout.CallsMade`).
    ``fatal`` says why no further episode can succeed either (refused credentials, a
    replay's cache miss): the run stops. The row has no control log nor run log, so those
    the episode wrote before it raised or its worker died are removed: no orphan beside it
    (a worker that died after writing its run log left a log saying ``ok`` beside a row
    saying ``error``)."""
    (Path(task.run_dir) / control_log_name(task.split, task.episode_id)).unlink(missing_ok=True)
    log_path(task.run_dir, task.split, task.episode_id).unlink(missing_ok=True)
    extra: dict[str, Any] = {
        **config_marks(config, task.config_json),
        "oracle": is_oracle(config.agent.name),
        "llm_backend": llm_backend(config),
        "detector": detector_name(config),
    }
    if wall_s is not None:
        extra["wall_s"] = round(wall_s, 6)
    if fatal is not None:
        extra["fatal"] = fatal
    return EpisodeResult(
        episode_id=task.episode_id,
        split=task.split,
        mode=config.episode_mode,
        system=config.system,
        status="error",
        visited_views=np.zeros((0, 4, 2)),
        gt_path_corners=ground_truth(episode),
        error=error,
        llm_calls=llm_calls,
        extra=extra,
    )
