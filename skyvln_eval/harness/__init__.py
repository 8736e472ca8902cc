"""The replay harness: run any agent configuration over episodes, resumably, at scale.

Follow one episode: :func:`run` converts the run's episodes to episode MCAPs (once, into
the cache), and each :class:`EpisodeTask` (:func:`run_episode_task`, in whichever worker
the executor picks) loads its episode and world, builds the agent and flies the episode
in official mode (:func:`run_official_episode`, the AVDN step) or dynamics mode
(:func:`run_dynamics_episode`, a controller on the quadrotor plant through obstacles),
then writes its run MCAP (:mod:`.run_log`) and returns an :class:`EpisodeResult` that the
coordinator appends to the run's ``results.jsonl`` (:class:`ResultStore`).
:func:`skyvln_eval.harness.plan.reproduce` runs a whole plan and writes the paper's tables.
"""

from skyvln_eval.harness.config import (
    DynamicsSettings,
    ObstacleSettings,
    RunConfig,
    load_run_config,
    run_config_from_mapping,
)
from skyvln_eval.harness.dynamics_loop import DynamicsRollout, run_dynamics_episode
from skyvln_eval.harness.executors import EXECUTOR_KINDS, Executor, make_executor
from skyvln_eval.harness.official_loop import (
    OfficialRollout,
    run_official_episode,
)
from skyvln_eval.harness.run import Progress, RunReport, error_verdict, resolve_data_dir, run
from skyvln_eval.harness.run_reading import run_results
from skyvln_eval.harness.runner import EpisodeTask, run_episode_task
from skyvln_eval.harness.store import ResultStore

__all__ = [
    "EXECUTOR_KINDS",
    "DynamicsRollout",
    "DynamicsSettings",
    "EpisodeTask",
    "Executor",
    "ObstacleSettings",
    "OfficialRollout",
    "Progress",
    "ResultStore",
    "RunConfig",
    "RunReport",
    "error_verdict",
    "load_run_config",
    "make_executor",
    "resolve_data_dir",
    "run",
    "run_config_from_mapping",
    "run_dynamics_episode",
    "run_episode_task",
    "run_official_episode",
    "run_results",
]
