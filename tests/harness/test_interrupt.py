"""Ctrl-C or SIGTERM stops a run at once and cleanly: the workers ended without a
traceback (processes) or left behind (threads waiting on a model), the finished episodes
kept, exit code 130, and the same command runs the rest."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from skyvln_eval.harness import RunConfig
from skyvln_eval.harness.store import RESULTS_FILE, ResultStore
from skyvln_eval.llm.loopback import LoopbackOpenAIServer
from tests.conftest import REPO
from tests.processes import as_a_terminal_job, children, still_alive_after
from tests.viewer.tools import skyvln_eval_command

EPISODES = 30


def _rows(run_dir: Path) -> int:
    return len(ResultStore(run_dir, repair=False)) if (run_dir / RESULTS_FILE).is_file() else 0


@contextlib.contextmanager
def _running(
    command: list[str], env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """``command`` in a process group of its own, as a terminal's job; killed with its
    group if the test leaves it running."""
    process = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=env,
        preexec_fn=as_a_terminal_job,
    )
    try:
        yield process
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)


def _under_way(process: subprocess.Popen[str], started: Callable[[], bool]) -> list[int]:
    """The worker processes of ``process`` once ``started()`` says its work is under way
    (it must not have ended by then: there would be nothing left to stop)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None and not started():
        time.sleep(0.02)
    workers = children(process.pid)
    assert workers and process.poll() is None, "it ended before it could be stopped"
    return workers


@pytest.mark.skipif(sys.platform != "linux", reason="reads the process tree from Linux /proc")
@pytest.mark.parametrize("stop", ["ctrl-c", "sigterm"])
def test_a_run_stopped_from_outside_ends_its_workers_and_resumes(
    tmp_path: Path, small_config: Callable[..., RunConfig], stop: str
) -> None:
    config = small_config(limit=EPISODES, workers=2, executor="processes", write_logs=False)
    path = tmp_path / "run.yaml"
    path.write_text(config.to_yaml())
    run_dir = tmp_path / "run"
    command = skyvln_eval_command("run", str(path), "--out", str(run_dir))
    with _running(command) as process:
        workers = _under_way(process, lambda: _rows(run_dir) >= 2)
        if stop == "ctrl-c":
            os.killpg(process.pid, signal.SIGINT)
        else:
            process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted: the episodes that finished are kept (" in err
    assert "finished in this launch; run.json lists those left)" in err
    assert "Traceback" not in out + err
    # The workers end with the run (and multiprocessing's resource tracker as soon as it
    # sees the run's end of its pipe close).
    assert not still_alive_after(workers, 10)
    kept = _rows(run_dir)
    assert 2 <= kept < EPISODES
    resumed = subprocess.run(
        command, stdin=subprocess.DEVNULL, capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"{kept} already done, {EPISODES - kept} run now" in resumed.stdout
    assert (run_dir / RESULTS_FILE).is_file()


def test_ctrl_c_stops_episodes_waiting_on_a_slow_llm_in_threads_at_once(
    tmp_path: Path, small_config: Callable[..., RunConfig]
) -> None:
    threads = 4
    # Answers take longer than the process needs to stop, even on a loaded machine: no call
    # ends between Ctrl-C and the exit, so none can start another (each episode's first
    # call, its sub-goals, is the only one it has made when Ctrl-C comes).
    with LoopbackOpenAIServer(latency_s=4.0) as slow:
        llm = {
            "backend": "openai:slow-model",
            "base_url": slow.base_url,
            "api_key_env": "SKYVLN_TEST_KEY",
            "send_task_data": True,
        }
        config = small_config(
            limit=8,
            workers=threads,
            executor="threads",
            write_logs=False,
            agent={"name": "skyvln", "llm": llm},
        )
        path = tmp_path / "run.yaml"
        path.write_text(config.to_yaml())
        command = skyvln_eval_command("run", str(path), "--out", str(tmp_path / "run"))
        with _running(command, env={**os.environ, "SKYVLN_TEST_KEY": "sk-test"}) as process:
            deadline = time.monotonic() + 120
            while len(slow.requests) < threads and time.monotonic() < deadline:
                time.sleep(0.05)
            assert process.poll() is None, "the run ended before it could be stopped"
            os.killpg(process.pid, signal.SIGINT)
            sent_before = len(slow.requests)
            _, err = process.communicate(timeout=60)
            time.sleep(1.0)  # a call made before the exit would have arrived by now
            sent_after = len(slow.requests) - sent_before
    assert process.returncode == 130, err
    assert "interrupted: the episodes that finished are kept" in err
    assert "Traceback" not in err
    # The episodes did not go on calling the model until they ended (each has many calls
    # left): at most the calls already on their way when Ctrl-C came.
    assert sent_after <= threads


@pytest.mark.skipif(sys.platform != "linux", reason="reads the process tree from Linux /proc")
def test_a_conversion_stopped_from_outside_says_so_and_leaves_whole_files(
    tmp_path: Path, sample_dir: Path
) -> None:
    # An audit: SIGTERM ended `convert` with exit 143, no word, and a temporary file left.
    out = tmp_path / "logs"
    folder = out / "train" / "andh"
    command = skyvln_eval_command(
        "convert", "--data-dir", str(sample_dir), "--split", "train", "--out", str(out),
        "--workers", "2",
    )  # fmt: skip
    with _running(command) as process:
        workers = _under_way(process, lambda: folder.is_dir() and any(folder.glob("*.mcap")))
        process.send_signal(signal.SIGTERM)
        out_text, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted: the episode logs written are kept" in err
    assert "Traceback" not in out_text + err
    assert not still_alive_after(workers, 10)
    again = subprocess.run(
        command, stdin=subprocess.DEVNULL, capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert again.returncode == 0, again.stderr
    assert not list(folder.glob(".*.tmp")), "the next conversion clears what was cut short"
