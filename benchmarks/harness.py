"""Benchmark: the replay harness at AVDN scale, and overlapping LLM calls.

1. Official mode: the full SkyVLN agent (rule backend) on the AVDN-sized synthetic
   val_unseen (411 episodes), ``--workers`` processes: episodes/s (aim: at least 30).
2. Dynamics mode: the same episodes flown with the NMPC through two moving obstacles:
   episodes/s, wall time (aim: at most 60 s on 2 cores) and the simulated-to-wall-clock
   time ratio.

Each row gives the peak resident memory of every worker process (``ru_maxrss`` read in
the worker after each episode).
3. LLM concurrency, against a loopback OpenAI-compatible server that answers after
   200 ms: 64 raw calls one after another vs 16 at a time (aim: at least 10x), and
   16 episodes of the agent with the ``openai`` backend run sequentially vs 16 at a time.

Run directories go to a temporary folder; episode logs and the dataset to the cache.

    python benchmarks/harness.py [--workers 2] [--limit N] [--skip-official] [--skip-dynamics]
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from skyvln_eval.harness import RunConfig, make_executor, run
from skyvln_eval.harness.executors import Executor
from skyvln_eval.harness.run import prepare_job
from skyvln_eval.llm.config import LLMConfig, build_client
from skyvln_eval.llm.loopback import LoopbackOpenAIServer
from skyvln_eval.llm.types import GenerationConfig, Message


def _measured(fn: Callable[[Any], Any], task: Any) -> tuple[Any, int, int]:
    """``fn(task)``, the worker's process id and its peak resident memory so far (KiB)."""
    return fn(task), os.getpid(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


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


def harness_row(label: str, config: RunConfig, run_dir: Path) -> None:
    prepare_job(config, run_dir)  # episode logs converted once, not timed
    executor = PeakMemory(make_executor(config.executor, config.workers))
    start = time.perf_counter()
    report = run(config, run_dir, executor=executor)
    wall = time.perf_counter() - start
    n = len(report.expected)
    ratio = report.simulated_s / wall if wall else float("nan")
    peaks = ", ".join(f"{kib / 1024:.0f}" for kib in sorted(executor.peak_kib.values()))
    print(
        f"{label:<28} {n:>5} episodes {wall:>7.1f} s  {n / wall:>6.2f} episodes/s  "
        f"simulated {report.simulated_s:>8.0f} s  ({ratio:>5.1f}x real time)  "
        f"failed {len(report.failed)}  peak RSS per worker (MiB): {peaks}"
    )


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
        harness_row(
            "official, full agent", RunConfig(system="official", **common), out / "official"
        )
    if not args.skip_dynamics:
        config = RunConfig(system="dynamics", mode="dynamics", **common)
        harness_row("dynamics, full agent, NMPC", config, out / "dynamics")
    if args.skip_llm:
        return
    os.environ.setdefault("BENCH_KEY", "sk-bench")
    with LoopbackOpenAIServer(latency_s=0.2) as server:
        sequential = llm_calls(server.base_url, 64, 1)
        concurrent = llm_calls(server.base_url, 64, 16)
        print(
            f"64 LLM calls, 200 ms each: sequential {sequential:.2f} s, "
            f"16 concurrent {concurrent:.2f} s -> {sequential / concurrent:.1f}x (aim: >= 10x)"
        )
        llm = {
            "backend": "openai:loopback",
            "base_url": server.base_url,
            "api_key_env": "BENCH_KEY",
            "max_concurrency": 16,
        }
        timings = {}
        for workers in (1, 16):
            config = RunConfig(
                system=f"openai x{workers}",
                data="sample",
                splits=("val_seen",),
                limit=16,
                workers=workers,
                executor="threads",
                write_logs=False,
                agent={"name": "skyvln", "llm": llm},
            )
            prepare_job(config, out / f"llm{workers}")
            start = time.perf_counter()
            report = run(config, out / f"llm{workers}", executor=make_executor("threads", workers))
            timings[workers] = time.perf_counter() - start
            assert report.complete and not report.failed, report.failed
        print(
            f"16 agent episodes over the 200 ms server: sequential {timings[1]:.1f} s, "
            f"16 at a time {timings[16]:.1f} s -> {timings[1] / timings[16]:.1f}x"
        )


if __name__ == "__main__":
    main()
