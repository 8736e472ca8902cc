"""Benchmark: the replay harness at AVDN scale, and overlapping LLM calls.

1. Official mode: the full SkyVLN agent (rule backend) on the AVDN-sized synthetic
   val_unseen (411 episodes), ``--workers`` processes: episodes/s (aim: at least 30).
2. Dynamics mode: the same episodes flown with the NMPC through two moving obstacles:
   episodes/s, wall time (aim: at most 60 s on 2 cores) and the simulated-to-wall-clock
   time ratio.

Each row gives the CPU time of the run (its worker processes and this one), the episodes
by status (a run with an error episode, or an incomplete one, stops the benchmark: its
throughput would not be the agent's) and the peak resident memory of every worker
process (its own ``VmHWM``, read in the worker after each episode).
3. LLM concurrency, against a loopback OpenAI-compatible server (in a process of its
   own, as a remote model is) that answers after 200 ms: 64 raw calls one after another
   vs 16 at a time (aim: at least 10x); 16 episodes of the agent with the ``openai``
   backend, in official and in dynamics mode, run sequentially vs 16 at a time (16
   threads in one process, and 2 processes x 8 threads), with the bound the longest
   episode sets (no schedule ends before it does) and the CPU time each schedule used (its
   threads and worker processes; 16 threads share one interpreter, so their Python work
   runs one thread at a time; aim: at least 12x, which the longest episode's own chain
   of calls may bound below: the row prints that bound); then the threads executor in
   dynamics mode, ``--repeats``
   times, to show it never crashes (threads never share a CasADi solver).
4. The two ways of overlapping LLM waits at a larger scale, where the processes' start-up
   is paid once for many episodes: ``--scale`` episodes (default 64) of the AVDN-sized
   val_unseen in each mode, 16 threads vs 2 processes x 8 threads (which the README's
   advice on executors for remote LLMs rests on).

Run directories go to a temporary folder; episode logs and the dataset to the cache.

    python benchmarks/harness.py [--workers 2] [--limit N] [--skip-official] [--skip-dynamics]
        [--skip-llm] [--repeats 10] [--scale 64] [--rounds 1]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from skyvln_eval.avdn.constants import Split
from skyvln_eval.harness import RunConfig, make_executor, run
from skyvln_eval.harness.executors import Executor
from skyvln_eval.harness.run import prepare_job
from skyvln_eval.llm.config import LLMConfig, build_client
from skyvln_eval.llm.types import GenerationConfig, Message
from skyvln_eval.metrics.results_io import read_results


def own_peak_kib() -> int:
    """This process's own peak resident memory (KiB): ``VmHWM``, which starts afresh at
    ``exec``. (``ru_maxrss`` does not: a spawned worker inherits the peak of the parent
    it was forked from, so a parent of 1.2 GiB showed every worker at 1.2 GiB.)"""
    try:
        with Path("/proc/self/status").open(encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # not Linux: an upper bound


def _measured(fn: Callable[[Any], Any], task: Any) -> tuple[Any, int, int]:
    """``fn(task)``, the worker's process id and its own peak resident memory so far."""
    return fn(task), os.getpid(), own_peak_kib()


class PeakMemory:
    """An executor that runs another and keeps each worker's peak resident memory."""

    def __init__(self, inner: Executor) -> None:
        self.inner = inner
        self.peak_kib: dict[int, int] = {}

    def map_unordered(
        self, fn: Callable[[Any], Any], tasks: Sequence[Any]
    ) -> Iterator[tuple[Any, Any]]:
        for task, outcome in self.inner.map_unordered(functools.partial(_measured, fn), tasks):
            if isinstance(outcome, tuple):
                result, pid, peak = outcome
                self.peak_kib[pid] = max(self.peak_kib.get(pid, 0), peak)
                yield task, result
            else:
                yield task, outcome


def harness_rows(label: str, config: RunConfig, run_dir: Path, rounds: int) -> None:
    """``rounds`` runs of ``config``, a row each, then (for several) the median wall time
    and the range: on a shared machine one run also measures the neighbours (the same
    code has measured 59 s and 69 s on one afternoon)."""
    runs = [harness_row(label, config, run_dir / f"round-{k}") for k in range(rounds)]
    if rounds > 1:
        walls, n = [wall for wall, _ in runs], runs[0][1]
        median = statistics.median(walls)
        print(
            f"{label:<28} median of {rounds} runs {median:.1f} s ({n / median:.2f} episodes/s), "
            f"range {min(walls):.1f}-{max(walls):.1f} s"
        )


def _statuses(statuses: dict[str, int]) -> str:
    """``ok 405, degraded 6``: a row of degraded episodes is not a row of the agent's."""
    return ", ".join(f"{status} {count}" for status, count in sorted(statuses.items()))


def harness_row(label: str, config: RunConfig, run_dir: Path) -> tuple[float, int]:
    """One run of ``config`` and its row; returns the wall time and the episodes."""
    prepare_job(config, run_dir)  # episode logs converted once, not timed
    executor = PeakMemory(make_executor(config.executor, config.workers))
    cpu_before = cpu_seconds()
    start = time.perf_counter()
    report = run(config, run_dir, executor=executor)
    wall = time.perf_counter() - start
    # The workers' CPU time as well: on a shared machine the wall time also measures the
    # neighbours, the CPU time much less so.
    cpu = cpu_seconds() - cpu_before
    n = len(report.expected)
    if not report.complete or report.errors:  # a throughput of failures is no figure
        raise SystemExit(f"{label}: {report.statuses}, errors {report.errors}")
    ratio = report.simulated_s / wall if wall else float("nan")
    peaks = ", ".join(f"{kib / 1024:.0f}" for kib in sorted(executor.peak_kib.values()))
    # Official mode flies nothing: its nominal step time is not simulated time.
    simulated = (
        f"simulated {report.simulated_s:>8.0f} s  ({ratio:>5.1f}x real time)  "
        if config.mode == "dynamics"
        else ""
    )
    print(
        f"{label:<28} {n:>5} episodes {wall:>7.1f} s  {n / wall:>6.2f} episodes/s  {simulated}"
        f"CPU {cpu:.0f} s ({1000 * cpu / n:.0f} ms per episode)  "
        f"{_statuses(report.statuses)}  peak RSS per worker (MiB): {peaks}"
    )
    return wall, n


def llm_calls(base_url: str, calls: int, concurrency: int) -> float:
    client = build_client(
        LLMConfig(
            backend="openai:loopback",
            base_url=base_url,
            api_key_env="BENCH_KEY",
            max_concurrency=concurrency,
        )
    )
    messages = [Message(role="user", text="Say hello.")]

    def one(_: int) -> None:
        result = client.call("bench", messages, GenerationConfig())
        assert result.text is not None, "the loopback server must answer"

    one(-1)  # not timed: the first call imports the openai client and opens a connection
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=concurrency) as pool:
        list(pool.map(one, range(calls)))
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--limit", type=int, default=None, help="episodes (default: all 411)")
    parser.add_argument("--skip-official", action="store_true")
    parser.add_argument("--skip-dynamics", action="store_true")
    parser.add_argument("--skip-llm", action="store_true")
    parser.add_argument("--repeats", type=int, default=10, help="repeated threads runs")
    parser.add_argument(
        "--rounds", type=int, default=1, help="runs of each AVDN-scale row (median printed)"
    )
    parser.add_argument(
        "--scale", type=int, default=64, help="episodes per executor at scale (0: skip)"
    )
    args = parser.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-harness-"))
    common = {
        "data": "full",
        "splits": ("val_unseen",),
        "limit": args.limit,
        "workers": args.workers,
        "executor": "processes",
        "write_logs": True,
    }
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; run folders under {out}")
    if not args.skip_official:
        config = RunConfig(system="official", **common)
        harness_rows("official, full agent", config, out / "official", args.rounds)
    if not args.skip_dynamics:
        config = RunConfig(system="dynamics", mode="dynamics", **common)
        harness_rows("dynamics, full agent, NMPC", config, out / "dynamics", args.rounds)
    if args.skip_llm:
        return
    os.environ.setdefault("BENCH_KEY", "sk-bench")
    with remote_loopback(latency_s=0.2) as base_url:
        sequential = llm_calls(base_url, 64, 1)
        concurrent = llm_calls(base_url, 64, 16)
        print(
            f"64 LLM calls, 200 ms each: sequential {sequential:.2f} s, "
            f"16 concurrent {concurrent:.2f} s -> {sequential / concurrent:.1f}x (aim: >= 10x)"
        )
        llm_episodes(base_url, out, args.repeats)
        if args.scale:
            executors_at_scale(base_url, out, args.scale)


@contextlib.contextmanager
def remote_loopback(latency_s: float) -> Iterator[str]:
    """The loopback server in a process of its own, as a remote model is: answering does
    not take the episodes' interpreter (its lock) from them. Yields the base URL."""
    server = subprocess.Popen(
        [sys.executable, "-m", "skyvln_eval.llm.loopback", "--latency-s", str(latency_s)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        yield server.stdout.readline().strip()
    finally:
        assert server.stdin is not None
        server.stdin.close()  # the server stops when its input closes
        server.wait(timeout=30)


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its children that have ended."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def llm_run(
    base_url: str,
    run_dir: Path,
    mode: str,
    executor: str,
    workers: int,
    threads: int,
    episodes: int = 16,
    data: tuple[str, Split] = ("sample", "val_seen"),
) -> tuple[float, float, float]:
    """Seconds for ``episodes`` agent episodes of the openai backend over the loopback
    server, from ``data`` (dataset, split), the longest episode's own wall time, and the
    CPU seconds the run used (the loopback server, still running, is not counted)."""
    llm = {
        "backend": "openai:loopback",
        "base_url": base_url,
        "api_key_env": "BENCH_KEY",
        "max_concurrency": 16,
        "send_task_data": True,  # the loopback server answers as the rule backend
    }
    config = RunConfig(
        system=f"openai {mode}",
        data=data[0],
        splits=(data[1],),
        limit=episodes,
        mode=mode,  # type: ignore[arg-type]
        workers=workers,
        executor=executor,  # type: ignore[arg-type]
        threads_per_worker=threads,
        write_logs=False,
        agent={"name": "skyvln", "llm": llm},  # type: ignore[arg-type]
    )
    prepare_job(config, run_dir)  # episode logs converted once, not timed
    cpu_before = cpu_seconds()
    start = time.perf_counter()
    report = run(config, run_dir)
    seconds = time.perf_counter() - start
    cpu = cpu_seconds() - cpu_before
    if not report.complete or report.errors or report.statuses != {"ok": episodes}:
        raise SystemExit(f"{mode} {executor}: {report.statuses}, errors {report.errors}")
    walls = [float(r.extra["wall_s"]) for r in read_results(run_dir / "results.jsonl")]
    return seconds, max(walls), cpu


def llm_episodes(base_url: str, out: Path, repeats: int) -> None:
    """16 episodes sequential vs 16 at a time: threads in one process, and 2 processes x 8
    threads; in official and dynamics mode; then the threads executor ``repeats`` times
    (threads must never share a CasADi solver: a crash there is a segfault)."""
    for mode in ("official", "dynamics"):
        # One untimed episode first: the map's look-up tables and the like are made once per
        # process, and the sequential run's first episode would carry them, which made
        # the longest episode, and so the bound printed, a start-up's and not a chain's.
        llm_run(base_url, out / f"{mode}-warm", mode, "serial", 1, 1, episodes=1)
        sequential, longest, sequential_cpu = llm_run(
            base_url, out / f"{mode}-seq", mode, "serial", 1, 1
        )
        threads, _, threads_cpu = llm_run(base_url, out / f"{mode}-thr", mode, "threads", 16, 1)
        hybrid, _, hybrid_cpu = llm_run(base_url, out / f"{mode}-hyb", mode, "processes", 2, 8)
        # No schedule finishes before the longest episode does: its chain of calls (each
        # waits for the answer before) and its own computing bound any speed-up.
        print(
            f"16 {mode} agent episodes over the 200 ms server: sequential {sequential:.1f} s, "
            f"CPU {sequential_cpu:.1f} s (longest episode {longest:.1f} s, so at most "
            f"{sequential / longest:.1f}x); 16 threads {threads:.1f} s, CPU {threads_cpu:.1f} s "
            f"-> {sequential / threads:.1f}x; 2 processes x 8 threads {hybrid:.1f} s, CPU "
            f"{hybrid_cpu:.1f} s -> {sequential / hybrid:.1f}x (aim: >= 12x)"
        )
    crashes = 0
    for k in range(repeats):
        try:
            llm_run(base_url, out / f"repeat-{k}", "dynamics", "threads", 16, 1)
        except SystemExit as error:
            crashes += 1
            print(f"repeat {k}: {error}")
    print(f"threads executor, dynamics mode, {repeats} repeated runs: {crashes} with errors")


def executors_at_scale(base_url: str, out: Path, episodes: int) -> None:
    """``episodes`` of the AVDN-sized val_unseen in each mode, 16 threads in one process vs
    2 processes x 8 threads."""
    split: tuple[str, Split] = ("full", "val_unseen")
    for mode in ("official", "dynamics"):
        threads, _, threads_cpu = llm_run(
            base_url, out / f"{mode}-scale-thr", mode, "threads", 16, 1, episodes, split
        )
        hybrid, _, hybrid_cpu = llm_run(
            base_url, out / f"{mode}-scale-hyb", mode, "processes", 2, 8, episodes, split
        )
        print(
            f"{episodes} {mode} agent episodes over the 200 ms server: 16 threads "
            f"{threads:.1f} s, CPU {threads_cpu:.1f} s; 2 processes x 8 threads {hybrid:.1f} s, "
            f"CPU {hybrid_cpu:.1f} s -> processes x threads {threads / hybrid:.2f}x as fast as "
            "the threads"
        )


if __name__ == "__main__":
    main()
