"""One run directory, one process: the same run launched twice at once runs each episode
once, the second launch says who holds the directory, and a killed holder frees it."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import yaml

from skyvln_eval.errors import RunDirBusyError
from skyvln_eval.harness import RunConfig
from skyvln_eval.harness.lock import RunDirLock
from skyvln_eval.harness.run import episode_logs
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import read_results
from tests.conftest import REPO, make_record, write_dataset

MakeConfig = Callable[..., RunConfig]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _console_script() -> list[str]:
    script = Path(sys.executable).with_name("skyvln-eval")
    return [str(script)] if script.exists() else [sys.executable, "-m", "skyvln_eval.cli"]


def test_the_same_run_launched_twice_at_once_runs_each_episode_once(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    config = small_config(
        limit=3, splits=("val_seen", "val_unseen"), write_logs=False, agent={"name": "random"}
    )
    config_file = tmp_path / "run.yaml"
    config_file.write_text(yaml.safe_dump(config.model_dump(mode="json")))
    run_dir = tmp_path / "run"
    command = [*_console_script(), "run", str(config_file), "--out", str(run_dir)]
    # A cache of their own: both launches convert the episode logs at the same moment too.
    env = {**ENV, "SKYVLN_EVAL_CACHE": str(tmp_path / "cache")}
    launches = [
        subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        for _ in range(2)
    ]
    outputs = [launch.communicate(timeout=300) for launch in launches]
    codes = [launch.returncode for launch in launches]
    rows = read_results(run_dir / RESULTS_FILE)
    assert len(rows) == 6 and len({r.key for r in rows}) == 6  # each episode exactly once
    # Which launch takes the directory first is up to the scheduler, and so is whether the
    # other asks while it is held (refused, exit 2) or after it let go (nothing left, exit 0).
    assert sorted(codes) in ([0, 0], [0, 2]), outputs
    winner = codes.index(0) if sorted(codes) == [0, 2] else _the_one_that_ran(outputs)
    loser = 1 - winner
    assert b"6 run now" in outputs[winner][0], outputs
    if codes[loser] == 2:
        refusal = outputs[loser][1].decode()
        assert f"run directory {run_dir} is in use by process {launches[winner].pid} (" in refusal
        assert f"run {config_file} --out {run_dir}), running since " in refusal
        assert "Wait for it to finish" in refusal and "Traceback" not in refusal
    else:
        assert b"nothing left to run: every episode was recorded before" in outputs[loser][1]


def _the_one_that_ran(outputs: list[tuple[bytes, bytes]]) -> int:
    ran = [i for i, (stdout, _) in enumerate(outputs) if b"6 run now" in stdout]
    assert len(ran) == 1, outputs
    return ran[0]


def test_a_launch_on_a_held_run_directory_is_refused_and_names_the_holder(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    """The refusal without a race: a process holds the directory for as long as the test
    needs, so the second launch always meets it."""
    config = small_config(limit=1, splits=("val_seen",), write_logs=False, agent={"name": "random"})
    config_file = tmp_path / "run.yaml"
    config_file.write_text(yaml.safe_dump(config.model_dump(mode="json")))
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with _held(run_dir) as holder:
        launch = subprocess.run(
            [*_console_script(), "run", str(config_file), "--out", str(run_dir)],
            cwd=REPO,
            env={**ENV, "SKYVLN_EVAL_CACHE": str(tmp_path / "cache")},
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert launch.returncode == 2, (launch.stdout, launch.stderr)
    assert f"run directory {run_dir} is in use by process {holder.pid} (python" in launch.stderr
    assert "running since " in launch.stderr and "Wait for it to finish" in launch.stderr
    assert "Traceback" not in launch.stderr
    assert not (run_dir / RESULTS_FILE).exists()  # the refused launch ran nothing


HOLDER = """
import sys, time
from skyvln_eval.harness.lock import RunDirLock
from skyvln_eval.harness.run import episode_logs
lock = RunDirLock(sys.argv[1])
lock.acquire()
print("held", flush=True)
time.sleep(600)
"""


@contextlib.contextmanager
def _held(run_dir: Path) -> Iterator[subprocess.Popen[str]]:
    """A process of its own holding ``run_dir``'s lock until the block ends (then killed)."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(run_dir)],
        cwd=REPO,
        env=ENV,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        yield holder
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait()


def test_the_lock_dies_with_its_process_even_when_killed(tmp_path: Path) -> None:
    with _held(tmp_path) as holder:
        with pytest.raises(RunDirBusyError) as busy:
            RunDirLock(tmp_path).acquire()
        assert busy.value.holder["pid"] == holder.pid
        assert f"in use by process {holder.pid} (python" in str(busy.value)
    deadline = time.monotonic() + 10
    lock = RunDirLock(tmp_path)
    while True:  # the kernel drops the lock as the process is reaped
        try:
            lock.acquire()
            break
        except RunDirBusyError:
            assert time.monotonic() < deadline, "a killed run's lock must not outlive it"
            time.sleep(0.05)
    assert lock.held
    lock.release()


def test_a_run_lets_go_of_its_directory_when_it_ends(tmp_path: Path) -> None:
    with RunDirLock(tmp_path) as lock:
        assert lock.held
        with pytest.raises(RunDirBusyError, match=f"process {os.getpid()} "):
            RunDirLock(tmp_path).acquire()  # even from this same process: no second run
    again = RunDirLock(tmp_path)
    again.acquire()
    again.release()


def test_runs_converting_the_same_episodes_at_once_do_not_trip_over_each_other(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Episode logs are converted into a cache that every run on the data shares: four
    runs starting together on fresh data (a new cache) each get every episode's log."""
    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(tmp_path / "cache"))
    records = [make_record(route_index=f"{i}_1") for i in range(40)]
    data = write_dataset(tmp_path / "data", {"val_unseen": records})
    config = RunConfig(system="x", data=str(data), splits=("val_unseen",))
    barrier = threading.Barrier(4)
    outcomes: list[object] = []

    def convert() -> None:
        barrier.wait()
        try:
            outcomes.append(episode_logs(config, data))
        except Exception as error:  # kept for the assertion below
            outcomes.append(error)

    threads = [threading.Thread(target=convert) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(outcomes) == 4, outcomes  # all() of none would pass
    assert all(isinstance(o, dict) and len(o) == 40 for o in outcomes), outcomes
    assert all(path.is_file() for o in outcomes for path in o.values())  # type: ignore[union-attr]


def test_a_launch_removes_only_the_temporaries_its_own_writers_leave(tmp_path: Path) -> None:
    # An audit lost a user's `docs/.draft.tmp` to `run --out` of a folder that held it:
    # every hidden .tmp file under the run directory was taken for a killed writer's.
    from skyvln_eval.harness.lock import remove_leftover_temporaries
    from skyvln_eval.harness.run import RUN_FILES, RUN_FOLDERS

    ours = [
        tmp_path / ".results.jsonl.k3j_x9a2.tmp",
        tmp_path / "logs" / "val_seen" / ".9101__5_1.mcap.abcd1234.tmp",
        tmp_path / "control" / "val_seen" / ".9101__5_1.parquet.zz99yy88.tmp",
    ]
    theirs = [
        tmp_path / "docs" / ".draft.tmp",
        tmp_path / ".notes.txt.abcd1234.tmp",  # looks like a writer's, not a run file's
        tmp_path / "logs" / "val_seen" / ".draft.tmp",
        tmp_path / "logs" / ".thesis.tex.abcd1234.tmp",
    ]
    for path in ours + theirs:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("x")
    assert remove_leftover_temporaries(tmp_path, RUN_FILES, RUN_FOLDERS) == len(ours)
    assert not any(p.exists() for p in ours)
    assert all(p.exists() for p in theirs)
