"""A progress bar for runs: episodes done, ETA, running success rate and LLM cost so far.

The rate, cost and counts are of the episodes this launch runs: a resumed run (or one
run again with ``--retry-failed``) says "SR this launch", since the episodes recorded
before are not in it.

The cost reads "n/a" while it is unknown: before the first episode, and for good once an
episode had an unpriced call (a model without a price, a server that reported no tokens,
an attempt refused for its credentials). An episode that raised keeps the calls it made
(:class:`~skyvln_eval.harness.rollout.CallsMade`). It reads "$0.0000" only when known
to be zero: calls priced at 0 (the rule stand-in, a free model) or no calls at all.
"""

from __future__ import annotations

from collections.abc import Sequence

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from skyvln_eval.harness.run import Progress as RunProgress
from skyvln_eval.harness.run import RunReport
from skyvln_eval.metrics.records import EpisodeResult


class RichRunProgress(RunProgress):
    """Shows one bar per run; the rest of the console keeps working (transient bars)."""

    def __init__(self, console: Console | None = None) -> None:
        self.console = console or Console(stderr=True)
        self._bar: Progress | None = None
        self._task: TaskID | None = None
        self.successes = 0
        self.scored = 0  # episodes with a ground truth to score against
        self.finished = 0
        self.oracle = 0  # the oracle's episodes: a reference, never in the live SR
        self.errors = 0
        self.degraded = 0
        self._spent_usd = 0.0  # of the priced calls; the total only if nothing is unpriced
        self._cached_usd = 0.0  # the part of it replayed from the response cache (not paid now)
        self._cost_unknown = False
        self._nothing_to_run = False
        self._resumed = False  # episodes recorded before: the live SR is of this launch's

    @property
    def cost_usd(self) -> float | None:
        """The LLM cost of the episodes finished so far, ``None`` while unknown (see the
        module docstring)."""
        return None if self._cost_unknown or not self.finished else self._spent_usd

    def _stats(self) -> str:
        if self._nothing_to_run:  # a resumed run with every episode recorded before
            return "nothing left to run: every episode was recorded before"
        if self.scored:
            rate = f"{100.0 * self.successes / self.scored:5.1f}%"
        elif not self.finished:
            rate = "  n/a"
        elif self.oracle == self.finished:  # it has a ground truth: it flies it
            rate = "n/a (the oracle: a reference)"
        else:  # nothing with a ground truth to score against
            rate = "n/a (no ground truth)"
        cost = "n/a" if self.cost_usd is None else f"${self.cost_usd:.4f}"
        if self.cost_usd is not None and self._cached_usd > 0.0:
            # A cached answer counts the cost of the call that made it, as the tables do;
            # paid now it was not.
            cost += f" (${self._cached_usd:.4f} of it from the cache)"
        health = (f", {self.errors} error" if self.errors else "") + (
            f", {self.degraded} degraded" if self.degraded else ""
        )
        label = "SR this launch" if self._resumed else "SR"
        return f"{label} {rate} | LLM {cost}{health}"

    def start(self, description: str, total: int, already_done: int) -> None:
        self._nothing_to_run = total > 0 and already_done >= total
        self._resumed = already_done > 0
        self._bar = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[stats]}"),
            console=self.console,
            transient=False,
        )
        self._bar.start()
        self._task = self._bar.add_task(
            description, total=total, completed=already_done, stats=self._stats()
        )

    def episode_done(self, result: EpisodeResult, success: bool | None) -> None:
        self.finished += 1
        # The oracle's episodes are a reference, not a result: never in the live SR.
        oracle = result.extra.get("oracle") is True
        self.oracle += int(oracle)
        counted = success is not None and not oracle
        self.scored += int(counted)
        self.successes += int(counted and bool(success))
        self.errors += int(result.status == "error")
        self.degraded += int(result.status == "degraded")
        priced = [c.cost_usd for c in result.llm_calls if c.cost_usd is not None]
        self._spent_usd += sum(priced)
        self._cached_usd += sum(
            c.cost_usd for c in result.llm_calls if c.cached and c.cost_usd is not None
        )
        self._cost_unknown |= len(priced) < len(result.llm_calls)
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, advance=1, stats=self._stats())

    def finish(self, reports: Sequence[RunReport]) -> None:
        if self._bar is not None:
            self._bar.stop()
