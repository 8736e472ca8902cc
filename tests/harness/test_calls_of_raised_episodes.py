"""An episode that raises keeps the LLM calls it made: their count, tokens and cost."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.errors import ActionParseError
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import MetricConventions, read_results, score_results

MakeConfig = Callable[..., RunConfig]


@pytest.mark.parametrize(
    ("error", "stop"),
    [
        (RuntimeError("a bug after the calls"), "raised"),  # out of the loop: no rollout left
        (ActionParseError("refused after the calls"), "error"),  # kept by the loop
    ],
)
def test_the_calls_of_a_decision_that_raised_still_count(
    tmp_path: Path,
    small_config: MakeConfig,
    monkeypatch: pytest.MonkeyPatch,
    error: Exception,
    stop: str,
) -> None:
    from skyvln_eval.harness import runner

    real_build = runner.build_agent
    agents: list[Any] = []

    def build(config: Any, *args: Any) -> Any:
        agent = real_build(config, *args)
        act, decisions = agent.act, []

        def act_then_raise(observation: Any) -> Any:
            decision = act(observation)  # the calls are made (and paid for)...
            decisions.append(decision)
            if len(decisions) == 2:
                raise error  # ...and the decision that made them is never handed on
            return decision

        agent.act = act_then_raise  # type: ignore[method-assign]
        agents.append(agent)
        return agent

    monkeypatch.setattr(runner, "build_agent", build)
    report = run(small_config(limit=1), tmp_path / "run")
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    made = agents[0].client.calls_made()
    assert row.status == "error" and len(report.errors) == 1
    assert (row.extra.get("stop_reason") or "raised") == stop
    # Every attempt the client made is in the row (the first decision's and the second's),
    # not only those of decisions handed on, and the scores count them.
    assert len(made) > 0 and len(row.llm_calls) == len(made)
    assert sorted(c.module for c in row.llm_calls) == sorted(c.module for c in made)
    scores = score_results([row], MetricConventions())
    assert scores.loc[0, "llm_calls"] == sum(c.final for c in made)
    assert scores.loc[0, "llm_prompt_tokens"] == sum(c.prompt_tokens or 0 for c in made) > 0


def test_view_says_an_episode_raised_before_writing_its_log(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # It said "the run has no run MCAPs under logs/" and nothing of why.
    from skyvln_eval.errors import ConfigError
    from skyvln_eval.harness import runner
    from skyvln_eval.viewer.logs import find_episode_logs

    def broken(config: Any, *args: Any) -> Any:
        raise RuntimeError("a bug before the first decision")

    monkeypatch.setattr(runner, "build_agent", broken)
    run(small_config(limit=1), tmp_path / "run")
    [row] = read_results(tmp_path / "run" / RESULTS_FILE)
    for episodes in ((), (row.episode_id,)):
        with pytest.raises(ConfigError) as info:
            find_episode_logs(tmp_path / "run", episodes)
        said = str(info.value)
        assert "1 episode(s) ended in error before writing one, e.g. " in said
        assert f"{row.split}/{row.episode_id}: RuntimeError: a bug before the first decision" in (
            said
        )


def test_viewing_a_whole_run_says_which_episodes_it_cannot_show(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit: the episode that raised (its log removed) was left out without a word.
    from skyvln_eval.harness import runner
    from skyvln_eval.viewer.logs import find_episode_logs, unlogged_note

    build, built = runner.build_agent, []

    def broken_once(config: Any, *args: Any) -> Any:
        built.append(config)
        if len(built) == 1:
            raise RuntimeError("a bug before the first decision")
        return build(config, *args)

    monkeypatch.setattr(runner, "build_agent", broken_once)
    run(small_config(limit=2, workers=1, executor="serial"), tmp_path / "run")
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    [raised] = [r for r in rows if r.status == "error"]
    assert len(find_episode_logs(tmp_path / "run")) == 1
    note = unlogged_note(tmp_path / "run") or ""
    assert note.startswith("1 episode(s) ended in error before writing one, e.g. ")
    assert f"{raised.split}/{raised.episode_id}: RuntimeError" in note


def test_an_episode_that_calls_sys_exit_is_an_error_row_and_the_run_goes_on(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit: a sys.exit in code an episode called ended the run (exit code 5, no row).
    import sys

    from skyvln_eval.harness import runner

    build = runner.build_agent
    calls = iter(range(100))

    def exits_once(config: Any, *args: Any) -> Any:
        if next(calls) == 0:
            sys.exit(5)
        return build(config, *args)

    monkeypatch.setattr(runner, "build_agent", exits_once)
    report = run(small_config(limit=2), tmp_path / "run")
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    assert report.complete and sorted(r.status for r in rows)[0] == "error"
    assert sum("SystemExit: 5" in (r.error or "") for r in rows) == 1


def test_the_row_of_an_episode_that_raised_keeps_no_orphan_control_log(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # A worker killed after the control log, before the run log: its error row has no
    # control log, and the parquet stayed beside it, read by nothing.
    from skyvln_eval.converters.reader import read_episode
    from skyvln_eval.harness.run import prepare_job
    from skyvln_eval.harness.runner import control_log_name, failed_result

    job = prepare_job(small_config(mode="dynamics", limit=1), tmp_path / "run")
    try:
        task = job.tasks[0]
        orphan = tmp_path / "run" / control_log_name(task.split, task.episode_id)
        orphan.parent.mkdir(parents=True, exist_ok=True)
        orphan.write_bytes(b"PAR1 written before the worker died PAR1")
        row = failed_result(job.config, task, read_episode(task.episode_log), "worker crashed")
    finally:
        job.release()
    assert row.status == "error" and row.control_log is None and not orphan.exists()
