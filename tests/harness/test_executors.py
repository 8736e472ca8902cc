"""Executors give the same results whatever their kind and worker count."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

from skyvln_eval.errors import ConfigError, UnknownNameError
from skyvln_eval.harness.executors import WORKER_GC_THRESHOLDS, make_executor


def square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError("three")
    return x * x


def exit_on_three(x: int) -> int:
    if x == 3:
        sys.exit(3)  # a library that ends the program: the task's failure, not the run's end
    return x


def sleep_long(task: tuple[str, int]) -> int:
    folder, x = task
    (Path(folder) / str(x)).touch()  # under way
    time.sleep(120)
    return x


def crash_worker(x: int) -> int:
    if x == 2:
        os._exit(1)  # the worker process dies
    return x


@pytest.mark.parametrize(("kind", "workers"), [("serial", 1), ("threads", 3), ("processes", 2)])
def test_results_do_not_depend_on_the_executor(kind: str, workers: int) -> None:
    results = dict(make_executor(kind, workers).map_unordered(square_or_fail, list(range(6))))
    assert {k: v for k, v in results.items() if k != 3} == {0: 0, 1: 1, 2: 4, 4: 16, 5: 25}
    assert isinstance(results[3], ValueError)


def collector(_: int) -> tuple[tuple[int, int, int], int]:
    import gc

    return gc.get_threshold(), gc.get_freeze_count()


def test_worker_processes_collect_less_and_leave_this_process_alone() -> None:
    import gc

    before = gc.get_threshold()
    results = dict(make_executor("processes", 2).map_unordered(collector, [0, 1, 2]))
    for thresholds, frozen in results.values():
        assert thresholds == WORKER_GC_THRESHOLDS
        assert frozen > 1000  # the modules the worker loaded
    assert gc.get_threshold() == before
    serial = dict(make_executor("serial", 1).map_unordered(collector, [0]))
    assert serial[0][0] == before


def slow_pid(x: int) -> tuple[int, int, str]:
    import threading

    time.sleep(0.3)  # waits as an LLM call would: threads of one process overlap
    return x, os.getpid(), threading.current_thread().name


def test_processes_with_threads_run_episodes_in_threads_in_several_processes() -> None:
    executor = make_executor("processes", 2, threads_per_worker=3)
    results = dict(executor.map_unordered(slow_pid, list(range(12))))
    assert sorted(results) == list(range(12)) and all(v[0] == k for k, v in results.items())
    assert len({pid for _, pid, _ in results.values()}) == 2  # two processes ...
    assert {name for _, _, name in results.values()} >= {"episode-0", "episode-1"}  # ... threads
    errors = dict(executor.map_unordered(square_or_fail, list(range(6))))
    assert isinstance(errors[3], Exception) and "three" in str(errors[3]) and errors[5] == 25
    # A process that dies takes only its episodes in flight: the rest are still run.
    crashed = dict(executor.map_unordered(crash_worker, list(range(8))))
    assert isinstance(crashed[2], Exception) and len(crashed) == 8
    assert sum(not isinstance(v, Exception) for v in crashed.values()) >= 5


def test_a_worker_process_that_dies_costs_only_the_episode_it_was_running() -> None:
    """The process is replaced; the episode it held but had not started runs elsewhere."""
    results = dict(make_executor("processes", 2).map_unordered(crash_worker, list(range(8))))
    assert isinstance(results[2], RuntimeError) and "exited with code 1" in str(results[2])
    assert {k: v for k, v in results.items() if k != 2} == {k: k for k in range(8) if k != 2}


@pytest.mark.parametrize("threads", [1, 2])
def test_one_worker_process_is_a_process_too(threads: int) -> None:
    # An audit: one worker ran in the caller's process, where a crash in native code ended
    # the run (and every resume crashed at the same episode).
    executor = make_executor("processes", 1, threads_per_worker=threads)
    results = dict(executor.map_unordered(crash_worker, list(range(5))))
    assert isinstance(results[2], RuntimeError) and "exited with code 1" in str(results[2])
    assert sum(not isinstance(v, Exception) for v in results.values()) >= 5 - threads


@pytest.mark.skipif(sys.platform != "linux", reason="reads the process tree from Linux /proc")
def test_workers_of_a_killed_parent_end_at_once_not_after_their_episode(tmp_path: Path) -> None:
    # An audit: they finished their episode (a log appeared 10 s after the parent died),
    # writing into a run directory whose lock was gone, beside a resume running it again.
    import signal
    import subprocess

    from tests.conftest import REPO
    from tests.processes import children, still_alive_after

    script = (
        "import sys\n"
        "from skyvln_eval.harness.executors import make_executor\n"
        "from tests.harness.test_executors import sleep_long\n"
        "tasks = [(sys.argv[1], 0), (sys.argv[1], 1)]\n"
        "list(make_executor('processes', 2).map_unordered(sleep_long, tasks))\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script, str(tmp_path)], cwd=REPO)
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)  # until both episodes are under way
        workers = children(parent.pid)
        assert len(list(tmp_path.iterdir())) == 2 and parent.poll() is None
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
    assert not still_alive_after(workers, 60)  # well short of the episodes' 120 s


def test_workers_that_die_while_starting_up_are_not_started_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from tests.harness.dies_in_workers import PARENT_ENV, identity

    monkeypatch.setenv(PARENT_ENV, str(os.getpid()))
    results = dict(make_executor("processes", 2).map_unordered(identity, list(range(5))))
    assert sorted(results) == list(range(5))
    assert all(
        isinstance(v, RuntimeError) and "no worker process left" in str(v) for v in results.values()
    )


def mark_started(task: tuple[str, int]) -> int:
    folder, x = task
    (Path(folder) / str(x)).touch()
    time.sleep(0.3)
    return x


def test_worker_processes_keep_one_task_queued_and_a_caller_that_stops_starts_no_more(
    tmp_path: Path,
) -> None:
    """A worker that finishes takes its queued task at once; when the caller stops after
    the first outcome (a fatal error), no task beyond those started is run."""
    outcomes = make_executor("processes", 2).map_unordered(
        mark_started, [(str(tmp_path), x) for x in range(8)]
    )
    for task, outcome in outcomes:
        assert outcome == task[1]
        # The caller is busy (recording the result): the queued tasks run meanwhile. Waited
        # for, not slept on: a loaded machine may take longer to start them.
        deadline = time.monotonic() + 60.0
        while len(list(tmp_path.iterdir())) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # room for a fifth to start, were the pool to start one
        break
    outcomes.close()  # as the harness's loop does when it breaks: the pool shuts down
    started = sorted(int(p.name) for p in tmp_path.iterdir())
    assert started == [0, 1, 2, 3], started  # two running, then each worker's queued one


@pytest.mark.parametrize(
    ("kind", "threads"), [("serial", 1), ("threads", 1), ("processes", 1), ("processes", 2)]
)
def test_a_task_that_calls_sys_exit_is_its_own_failure(kind: str, threads: int) -> None:
    # An audit: it hung the processes executor (the worker's receiver thread kept the
    # process alive) and ended a run of the others with exit code 5 and no row.
    executor = make_executor(kind, 2, threads_per_worker=threads)  # type: ignore[arg-type]
    results = dict(executor.map_unordered(exit_on_three, list(range(6))))
    assert isinstance(results.pop(3), SystemExit)
    assert results == {k: k for k in range(6) if k != 3}


def test_bad_executor_settings() -> None:
    with pytest.raises(UnknownNameError, match="Did you mean 'threads'"):
        make_executor("thread", 2)
    with pytest.raises(ConfigError, match="at least 1"):
        make_executor("processes", 0)


def test_ray_executor_matches_the_local_one() -> None:
    pytest.importorskip(
        "ray", reason="the ray extra is not installed: pip install 'skyvln-eval[ray]'"
    )
    local = dict(make_executor("serial", 1).map_unordered(square_or_fail, list(range(5))))
    remote = dict(make_executor("ray", 2).map_unordered(square_or_fail, list(range(5))))
    assert {k: v for k, v in remote.items() if k != 3} == {k: v for k, v in local.items() if k != 3}
    assert isinstance(remote[3], Exception) and "three" in str(remote[3])
