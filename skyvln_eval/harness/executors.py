"""Executors: run one function over many episode tasks and yield results as they finish.

- ``serial``: in this process, one at a time (debugging, tiny runs).
- ``processes``: worker processes, each with its own pipe; the default for CPU-bound runs
  (rule backend, NMPC). Results do not depend on the worker count: each task is seeded
  by itself. A process that dies costs only the episodes it was running.
- ``threads``: a thread pool in this process, for runs that mostly wait on a remote LLM:
  while one episode waits on its LLM, the others proceed.
- ``processes`` with ``threads_per_worker > 1``: worker processes that each run several
  episodes in threads, for runs that wait on a remote LLM *and* compute (rendering,
  control): the waits overlap in each process, the computing spreads over the cores.
- ``ray``: Ray tasks on an existing cluster (``address``) or a local instance, for users
  who outgrow one machine (``pip install 'skyvln-eval[ray]'``; imported only when used).

The task function must not raise for an episode's own failures (the episode runner turns
them into failed rows); anything that still escapes (a crashed worker process, a lost
Ray node) is yielded as the exception, so the caller can record it and carry on.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import gc
import multiprocessing
import os
import pickle
import queue
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from multiprocessing import connection as mp_connection
from typing import Any, Final, Literal, Protocol, TypeVar

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


def episodes_are_the_parallelism() -> None:
    """Let OpenCV run its work in the calling thread: with episodes already running in
    parallel (processes, threads), its own thread pool only oversubscribes the cores."""
    import cv2

    cv2.setNumThreads(1)


#: A worker process's collection thresholds: a young collection every 10,000 net container
#: allocations, not Python's 700 (the older generations keep their ratios of 10).
WORKER_GC_THRESHOLDS = (10_000, 10, 10)


def collect_for_a_worker() -> None:
    """Tune the garbage collector of a process that only runs tasks: what it has loaded
    (modules, the task function) is frozen out of every collection, and young collections
    are rarer. Episodes allocate many short-lived dicts and lists, so Python collected
    hundreds of times per episode, each older collection walking all 115,000 objects the
    process had loaded: on dynamics episodes 4.8 ms of collection per episode, 0.2 after."""
    gc.freeze()
    gc.set_threshold(*WORKER_GC_THRESHOLDS)


@contextlib.contextmanager
def _native_threads_off(parallel: bool) -> Iterator[None]:
    """:func:`episodes_are_the_parallelism` for this process, until the block ends (when
    episodes run in ``parallel``)."""
    import cv2

    if not parallel:
        yield
        return
    before = cv2.getNumThreads()
    episodes_are_the_parallelism()
    try:
        yield
    finally:
        cv2.setNumThreads(before)


#: What a task may raise that is its own failure, recorded as such: any error, and a
#: ``sys.exit`` in code it calls (which would otherwise end a run, or hang a worker
#: process whose episode loop it ended). Ctrl-C is not a task's failure.
TASK_FAILURES: Final = (Exception, SystemExit)


@dataclass(frozen=True)
class SerialExecutor:
    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        for task in tasks:
            try:
                yield task, fn(task)
            except TASK_FAILURES as exc:  # recorded by the caller as a failed episode
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
                except TASK_FAILURES as exc:  # the caller records it
                    outcome = exc
                yield task, outcome
                submit_next()
    finally:
        for future in running:
            future.cancel()


@dataclass(frozen=True)
class ThreadExecutor:
    workers: int

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        with _native_threads_off(self.workers > 1):
            pool = cf.ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="episode")
            wait = True
            try:
                yield from _drain(pool, fn, tasks, self.workers)
            except KeyboardInterrupt:
                # Ctrl-C: running episodes cannot be stopped in their threads; the caller
                # ends the process (see cli._stoppable) instead of waiting for them.
                wait = False
                raise
            finally:
                pool.shutdown(wait=wait, cancel_futures=True)


class WorkerDied(RuntimeError):
    """The worker process running a task ended before the task did (a crash in native
    code, a kill)."""


class NoWorkerLeft(WorkerDied):
    """The task never started: every worker process died (each one, say, while starting
    up). Not the task's outcome: a caller runs it again once the cause is fixed."""


def _sendable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its type and message."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _process_worker(
    fn: Callable[[Any], Any], conn: Any, threads: int
) -> None:  # pragma: no cover - runs in a child process (covered through the executor's tests)
    """A worker process: ``threads`` threads run the tasks the parent sends down ``conn``
    (its own pipe), each announced (``start``) before it runs and its result sent back;
    ``None`` (or the parent gone) ends the work, and the tasks still waiting are then
    dropped, not run. With one thread the episodes run in the main thread and a second
    thread receives (episodes in a thread of their own took 25 MB more per process).

    Ctrl-C is the parent's to handle (it reaches the whole process group in a terminal):
    the parent ends its workers. A parent gone without a word (killed) ends the worker at
    once, its episode unfinished: there is no one to send the result to."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    episodes_are_the_parallelism()
    collect_for_a_worker()
    sending = threading.Lock()
    inbox: queue.Queue[Any] = queue.Queue()

    def send(message: tuple[str, int, Any]) -> None:
        with sending:
            conn.send(message)

    def run_tasks() -> None:
        with contextlib.suppress(OSError):  # the parent is gone (its end of the pipe closed)
            while (item := inbox.get()) is not None:
                index, task = item
                send(("start", index, None))
                try:
                    outcome: tuple[str, int, Any] = ("done", index, fn(task))
                except TASK_FAILURES as exc:  # the caller records it as a failed episode
                    outcome = ("error", index, _sendable(exc))
                send(outcome)

    def receive() -> None:
        try:
            while (message := conn.recv()) is not None:
                inbox.put(message)
        except (EOFError, OSError):
            # The parent is gone (killed): end at once. Finishing the episode under way
            # sent its result to no one, and wrote into a run directory whose lock was
            # gone, beside a resume that ran the same episode again (an audit saw a log
            # appear 10 s after the parent died).
            os._exit(0)
        with contextlib.suppress(queue.Empty):  # the parent stopped: start nothing more
            while True:
                inbox.get_nowait()
        for _ in range(threads):
            inbox.put(None)

    if threads == 1:
        # A daemon: were the episode loop to end another way, the process still ends.
        receiver = threading.Thread(target=receive, name="receiver", daemon=True)
        receiver.start()
        run_tasks()
        receiver.join()
        return
    pool = [threading.Thread(target=run_tasks, name=f"episode-{k}") for k in range(threads)]
    for thread in pool:
        thread.start()
    receive()
    for thread in pool:
        thread.join()


@contextlib.contextmanager
def _born_ignoring_ctrl_c() -> Iterator[None]:
    """Processes started in this block ignore SIGINT from their first instruction.

    Ctrl-C reaches a terminal's whole process group: a worker still importing, before its
    own code ignores SIGINT, printed a KeyboardInterrupt traceback. An ignored signal stays
    ignored across fork and exec (a blocked one does not here: multiprocessing's start
    clears the mask) and Python then installs no handler of its own. The price: a Ctrl-C
    in the few milliseconds of a start is not seen by the parent either (press it again).
    Only the main thread may change a handler; elsewhere nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)


@dataclass(frozen=True)
class ProcessExecutor:
    """``workers`` processes, each running ``threads`` episodes at a time in threads.

    Each process has its own pipe (no lock is shared between processes, so one that dies
    cannot block the others) and holds ``queued`` episodes beyond those its threads run:
    a thread that finishes starts the next at once, instead of idling while the parent
    records the result and sends another (4 ms an episode, 2% of an official run). The
    parent refills a process as its results come back. A process that dies (a crash in
    native code, the out-of-memory killer) takes only the episodes it had started with
    it: they are yielded as errors; those it held but had not started go to the other
    processes, and a new process takes its place (not for one that died before starting
    any episode: that would only die again). A caller that stops (a fatal error) starts
    no further episode: the processes finish the ones they are running and drop the rest.
    """

    workers: int
    threads: int = 1
    queued: int = 1

    def map_unordered(
        self, fn: Callable[[T], R], tasks: Sequence[T]
    ) -> Iterator[tuple[T, R | BaseException]]:
        # "spawn": fresh interpreters, safe with threads in the parent (progress bars, solvers).
        context = multiprocessing.get_context("spawn")
        todo = list(enumerate(tasks))[::-1]  # popped from the end: in order
        workers = [self._start(context, fn) for _ in range(min(self.workers, max(1, len(tasks))))]
        try:
            # Dealt one at a time, in turn: neighbouring episodes (often the same map, of
            # similar length) go to different processes, which spreads the work.
            for _ in range(self.threads + self.queued):
                for worker in workers:
                    self._feed(worker, todo, up_to=len(worker.in_flight) + 1)
            while any(w.alive and w.in_flight for w in workers):
                ready = mp_connection.wait([w.conn for w in workers if w.alive], timeout=1.0)
                for worker in (w for w in workers if w.conn in ready):
                    try:
                        kind, index, payload = worker.conn.recv()
                    except (EOFError, OSError):  # the process died
                        yield from self._lost(worker, tasks, todo)
                        # One that died in an episode (not while starting up) is replaced.
                        if worker.ran_episodes and todo:
                            workers.append(self._start(context, fn))
                        for other in workers:  # its unstarted episodes go to the others
                            self._feed(other, todo)
                        continue
                    if kind == "start":
                        worker.started.add(index)
                        worker.ran_episodes = True
                        continue
                    worker.in_flight.discard(index)
                    worker.started.discard(index)
                    yield tasks[index], payload
                    self._feed(worker, todo)
                if not any(w.alive for w in workers):
                    break
            for index, _ in reversed(todo):  # only if every process died
                yield tasks[index], NoWorkerLeft("no worker process left to run the episode")
        except KeyboardInterrupt:
            # Ctrl-C (or SIGTERM, see skyvln_eval.interrupts): the episodes under way are
            # dropped at once, not waited for; a resumed run runs them again.
            for worker in workers:
                worker.end_now()
            raise
        finally:
            for worker in workers:  # all asked first: they wind down at the same time
                worker.ask_to_stop()
            for worker in workers:
                worker.stop()

    def _start(self, context: Any, fn: Callable[[Any], Any]) -> _Worker:
        parent_end, child_end = context.Pipe()
        process = context.Process(target=_process_worker, args=(fn, child_end, self.threads))
        with _born_ignoring_ctrl_c():
            process.start()
        child_end.close()
        return _Worker(process, parent_end)

    def _feed(self, worker: _Worker, todo: list[tuple[int, Any]], up_to: int | None = None) -> None:
        """Give ``worker`` episodes until it holds one per thread plus ``queued`` (or
        ``up_to``)."""
        limit = self.threads + self.queued
        limit = limit if up_to is None else min(up_to, limit)
        while worker.alive and todo and len(worker.in_flight) < limit:
            index, task = todo.pop()
            try:
                worker.conn.send((index, task))
            except OSError:  # it died: its pipe reports the end, and _lost takes it from there
                todo.append((index, task))
                return
            worker.in_flight.add(index)

    @staticmethod
    def _lost(
        worker: _Worker, tasks: Sequence[T], todo: list[tuple[int, Any]]
    ) -> Iterator[tuple[T, BaseException]]:
        """The episodes of a process that died: errors for those it had started; the
        others back at the front of ``todo``."""
        worker.alive = False
        worker.process.join(timeout=5)
        code = worker.process.exitcode
        for index in sorted(worker.in_flight - worker.started, reverse=True):
            todo.append((index, tasks[index]))
        for index in sorted(worker.in_flight & worker.started):
            yield tasks[index], WorkerDied(f"worker process exited with code {code}")
        worker.in_flight.clear()
        worker.started.clear()


@dataclass(eq=False)
class _Worker:
    """One worker process of :class:`ProcessExecutor`, its pipe, the episodes it holds and
    those of them it has started."""

    process: Any
    conn: Any
    in_flight: set[int] = field(default_factory=set)
    started: set[int] = field(default_factory=set)
    ran_episodes: bool = False
    alive: bool = True

    def ask_to_stop(self) -> None:
        if self.alive:
            with contextlib.suppress(OSError):
                self.conn.send(None)

    def end_now(self) -> None:
        """End the process without waiting for its episodes."""
        self.alive = False
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=5)

    def stop(self) -> None:
        """Wait for the process to end (after :meth:`ask_to_stop`), ending it if it hangs."""
        self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=5)
        self.conn.close()


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


def make_executor(
    kind: str, workers: int, address: str | None = None, threads_per_worker: int = 1
) -> Executor:
    """An executor by name (``serial``, ``processes``, ``threads``, ``ray``); ``processes``
    with ``threads_per_worker > 1`` runs that many episodes in threads in each process."""
    if workers < 1 or threads_per_worker < 1:
        raise ConfigError(
            f"workers and threads_per_worker must be at least 1, got {workers} and "
            f"{threads_per_worker}"
        )
    # An option the chosen executor does not use would be ignored without a word.
    if threads_per_worker > 1 and kind != "processes":
        raise ConfigError(
            f"threads_per_worker ({threads_per_worker}) is for the processes executor, not "
            f"{kind!r} (threads: set workers to the episodes in flight)"
        )
    if address is not None and kind != "ray":
        raise ConfigError(f"ray_address ({address!r}) is for the ray executor, not {kind!r}")
    if kind == "serial":
        return SerialExecutor()
    # One worker process too: it was run in this process, where a crash in native code
    # ended the run, and every resume crashed at the same episode.
    if kind == "processes":
        return ProcessExecutor(workers, threads_per_worker)
    if kind == "threads":
        return ThreadExecutor(workers)
    if kind == "ray":
        return RayExecutor(workers, address)
    raise UnknownNameError("executor", kind, EXECUTOR_KINDS)
