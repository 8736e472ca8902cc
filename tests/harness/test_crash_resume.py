"""A run killed with SIGKILL again and again, at seeded points inside result rows and run
MCAPs, resumes to exactly the rows and scores of a run that was never interrupted."""

from __future__ import annotations

import multiprocessing
import os
import random
import signal
from collections import Counter
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path

import pytest
import yaml

from skyvln_eval.converters.validate import check_log
from skyvln_eval.harness import RunConfig, make_executor, run
from skyvln_eval.harness.crashpoints import CRASH_ENV, SITES
from skyvln_eval.harness.run_check import check_run_directory
from skyvln_eval.harness.runner import log_path
from skyvln_eval.harness.store import DAMAGED_FILE, RESULTS_FILE, ResultStore
from skyvln_eval.metrics import read_results
from tests.conftest import CliOutcome
from tests.harness.compare import same_runs

MakeConfig = Callable[..., RunConfig]
SEED = 20151
KILLS = 24
#: Every PROGRESS_EVERY-th kill lets one more episode finish first, so that the kills fall
#: on every episode of the run, not only on the first one left.
PROGRESS_EVERY = 4
EPISODES = 6


def _kill_server(conn: Connection, config_json: str, reference_dir: str, run_dir: str) -> None:
    """In a fresh interpreter: run the reference (which warms the caches: modules, maps,
    episode logs), then fork one child per crash point received, each resuming the run
    until the crash point kills it. Forking a warm, single-threaded process makes a kill
    cost one episode, not an interpreter start."""
    import cv2

    cv2.setNumThreads(0)  # no OpenCV worker threads: the server stays single-threaded
    config = RunConfig.model_validate_json(config_json)
    run(config, reference_dir)
    while (crash_at := conn.recv()) is not None:
        pid = os.fork()
        if pid == 0:  # the child: never returns into this loop
            code = 1
            try:
                os.environ[CRASH_ENV] = crash_at
                run(config, run_dir)
                code = 0
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
        conn.send(os.waitstatus_to_exitcode(status))


def test_sigkill_at_seeded_points_in_every_write_then_resume_loses_and_repeats_nothing(
    tmp_path: Path, small_config: MakeConfig, cli: Callable[..., CliOutcome]
) -> None:
    # The random agent keeps each episode short; what is tested is how rows and run MCAPs
    # are written and resumed, which is the same for every agent.
    config = small_config(limit=EPISODES, agent={"name": "random"}, observations_in_logs=False)
    run_dir = tmp_path / "killed"
    ours, theirs = multiprocessing.Pipe()
    server = multiprocessing.get_context("spawn").Process(
        target=_kill_server,
        args=(theirs, config.model_dump_json(), str(tmp_path / "reference"), str(run_dir)),
    )
    server.start()
    rng = random.Random(SEED)
    kills: list[str] = []
    try:
        for point in range(KILLS):
            left = EPISODES - len(ResultStore(run_dir, repair=False))
            site = rng.choice(SITES)
            occurrence = 2 if point % PROGRESS_EVERY == PROGRESS_EVERY - 1 and left > 1 else 1
            crash_at = f"{site}:{occurrence}:{rng.random():.3f}"
            ours.send(crash_at)
            assert ours.poll(120), f"kill {point} ({crash_at}) timed out"
            assert ours.recv() == -signal.SIGKILL, f"kill {point} ({crash_at}) did not happen"
            kills.append(crash_at)
    finally:
        ours.send(None)
        server.join(timeout=60)
    reference = read_results(tmp_path / "reference" / RESULTS_FILE)
    assert len(reference) == EPISODES
    done = len(ResultStore(run_dir, repair=False))
    assert 0 < done < len(reference), "the kills must leave work for the resume"
    assert set(Counter(k.split(":")[0] for k in kills)) == set(SITES)

    config_file = tmp_path / "run.yaml"
    config_file.write_text(yaml.safe_dump(config.model_dump(mode="json")))
    resumed = cli("run", str(config_file), "--out", str(run_dir))
    assert resumed.code == 0, resumed
    same_runs(read_results(run_dir / RESULTS_FILE), reference)
    logs = sorted(run_dir.rglob("*.mcap"))
    assert len(logs) == len(reference)
    assert all(not check_log(log).issues for log in logs)
    assert not list(run_dir.rglob(".*.tmp")), "no half-written file may stay behind"
    # Every row cut short by a kill was set aside (with its line number), none dropped.
    row_kills = sum(k.startswith("results-row") for k in kills)
    aside = (run_dir / DAMAGED_FILE).read_text().splitlines()[1:]
    assert 0 < len(aside) <= row_kills
    assert all('"reason":"incomplete last row' in line for line in aside)


def test_a_worker_process_killed_in_an_episode_costs_that_episode_and_the_run_goes_on(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every worker process (the replacements too) is killed at the end of its second
    episode's run MCAP: those episodes are errors that name the kill, the others are
    recorded, the run finishes; retrying the failed ones gives the uninterrupted run."""
    config = small_config(limit=EPISODES, agent={"name": "random"}, workers=2, executor="processes")
    monkeypatch.setenv(CRASH_ENV, "run-log-end:2")
    killed = run(config, tmp_path / "killed")
    rows = read_results(tmp_path / "killed" / RESULTS_FILE)
    assert len(rows) == EPISODES and len(killed.errors) == sum(r.status == "error" for r in rows)
    errors = [r for r in rows if r.status == "error"]
    assert 0 < len(errors) < EPISODES
    assert all("worker process exited with code -9" in (r.error or "") for r in errors)
    monkeypatch.delenv(CRASH_ENV)
    run(config, tmp_path / "killed", retry_failed=True)
    serial = config.model_copy(update={"workers": 1, "executor": "serial"})
    run(serial, tmp_path / "reference")
    same_runs(
        read_results(tmp_path / "killed" / RESULTS_FILE),
        read_results(tmp_path / "reference" / RESULTS_FILE),
    )


def test_a_worker_that_dies_after_writing_its_run_log_leaves_no_log_beside_its_error_row(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit: the log said ok, the row error, and `validate` said ok; the viewer would
    # have shown the episode as it was written.
    config = small_config(limit=4, agent={"name": "random"}, workers=2, executor="processes")
    monkeypatch.setenv(CRASH_ENV, "run-log-written:2")
    run(config, tmp_path / "killed")
    rows = read_results(tmp_path / "killed" / RESULTS_FILE)
    errors = [r for r in rows if r.status == "error"]
    assert errors and len(rows) == 4
    for row in rows:
        assert log_path(tmp_path / "killed", row.split, row.episode_id).is_file() == (
            row.status != "error"
        )
    assert not check_run_directory(tmp_path / "killed").problems


def test_episodes_no_worker_process_could_run_are_not_recorded_and_a_resume_runs_them(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit: workers that all died while starting up left every episode an 'error' row
    # ("no worker process left"), which a resume kept: they looked like the agent's.
    from tests.harness.dies_in_workers import PARENT_ENV, identity

    config = small_config(limit=2, agent={"name": "random"}, workers=2, executor="processes")
    monkeypatch.setenv(PARENT_ENV, str(os.getpid()))
    report = run(config, tmp_path / "run", task_function=identity)  # type: ignore[arg-type]
    assert report.stopped is not None and "no worker process left" in report.stopped
    assert not report.complete and len(report.missing) == 2 and not report.errors
    assert not (tmp_path / "run" / RESULTS_FILE).is_file() or not read_results(
        tmp_path / "run" / RESULTS_FILE
    )
    monkeypatch.delenv(PARENT_ENV)
    resumed = run(config, tmp_path / "run", executor=make_executor("serial", 1))
    assert resumed.complete and resumed.ran_now == 2 and not resumed.errors
