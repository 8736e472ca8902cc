"""Executors: run one function over many episode tasks and yield results as they finish.

- ``serial``: in this process, one at a time (debugging, tiny runs).
- ``processes``: a local process pool; the default for CPU-bound runs (rule backend,
  NMPC). Results do not depend on the worker count: each task is seeded by itself.
- ``threads``: a thread pool in this process, for runs that mostly wait on a remote LLM:
  while one episode waits on its LLM, the others proceed.
- ``ray``: Ray tasks on an existing cluster (``address``) or a local instance, for users
  who outgrow one machine (``pip install 'skyvln-eval[ray]'``; imported only when used).

The task function must not raise for an episode's own failures (the episode runner turns
them into failed rows); anything that still escapes (a crashed worker process, a lost
Ray node) is yielded as the exception, so the caller can record it and carry on.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol, TypeVar

from skyvln_eval.errors import ConfigError, UnknownNameError

T = TypeVar("T")
R = TypeVar("R")
ExecutorKind = Literal["serial", "processes", "threads", "ray"]
EXECUTOR_KINDS: tuple[ExecutorKind, ...] = ("serial", "processes", "threads", "ray")


class Executor(Protocol):
    """Runs ``fn`` over ``tasks``; yields ``(task, result or exception)`` as each finishes."""

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]: ...


@dataclass(frozen=True)
class SerialExecutor:
    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        for task in tasks:
            try:
                yield task, fn(task)
            except Exception as exc:  # recorded by the caller as a failed episode
                yield task, exc


def _drain(
    pool: cf.Executor, fn: Callable[[T], R], tasks: Sequence[T], workers: int
) -> Iterator[tuple[T, R | BaseException]]:
    """Yield each task's outcome as it finishes, with at most ``workers`` tasks submitted.

    The next task is submitted only once the caller has taken an outcome and asked for
    more, so a caller that stops (a fatal error: refused credentials, a full disk) starts
    no further episode: only those already running finish.
    """
    waiting = list(reversed(tasks))  # popped from the end: in the given order
    running: dict[cf.Future[R], T] = {}

    def submit_next() -> None:
        if waiting:
            task = waiting.pop()
            running[pool.submit(fn, task)] = task

    for _ in range(workers):
        submit_next()
    try:
        while running:
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            for future in done:
                task = running.pop(future)
                try:
                    outcome: R | BaseException = future.result()
                except Exception as exc:  # e.g. BrokenProcessPool: the caller records it
                    outcome = exc
                yield task, outcome
                submit_next()
    finally:
        for future in running:
            future.cancel()


@dataclass(frozen=True)
class ProcessExecutor:
    workers: int

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        # "spawn": fresh interpreters, safe with threads in the parent (progress bars, solvers).
        context = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=context) as pool:
            yield from _drain(pool, fn, tasks, self.workers)


@dataclass(frozen=True)
class ThreadExecutor:
    workers: int

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        with cf.ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="episode") as pool:
            yield from _drain(pool, fn, tasks, self.workers)


@dataclass(frozen=True)
class RayExecutor:
    """Ray tasks, one per episode; connects to ``address`` or starts a local instance."""

    workers: int
    address: str | None = None

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        ray = import_ray()
        started_here = not ray.is_initialized()
        if started_here:
            options: dict[str, Any] = (
                {"address": self.address} if self.address else {"num_cpus": self.workers}
            )
            ray.init(
                include_dashboard=False, log_to_driver=False, configure_logging=False, **options
            )
        remote = ray.remote(num_cpus=1, max_retries=0)(fn)
        pending = {remote.remote(task): task for task in tasks}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    task = pending.pop(ref)
                    try:
                        yield task, ray.get(ref)
                    except Exception as exc:  # RayTaskError, worker crash: recorded by the caller
                        yield task, exc
        finally:
            for ref in pending:
                ray.cancel(ref)
            if started_here:
                ray.shutdown()


def import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("the Ray executor needs Ray: pip install 'skyvln-eval[ray]'") from exc
    return ray


def make_executor(kind: str, workers: int, address: str | None = None) -> Executor:
    """An executor by name (``serial``, ``processes``, ``threads``, ``ray``)."""
    if workers < 1:
        raise ConfigError(f"workers must be at least 1, got {workers}")
    if kind == "serial" or (kind == "processes" and workers == 1):
        return SerialExecutor()
    if kind == "processes":
        return ProcessExecutor(workers)
    if kind == "threads":
        return ThreadExecutor(workers)
    if kind == "ray":
        return RayExecutor(workers, address)
    raise UnknownNameError("executor", kind, EXECUTOR_KINDS)
