"""Crash points: a test hook that kills this process (SIGKILL) in the middle of a write.

Resumption is only proven by killing runs where it hurts: halfway through a result row,
halfway through an episode's run MCAP. With ``SKYVLN_EVAL_CRASH_AT=<site>:<n>[:<fraction>]``
in the environment, the ``n``-th write at ``site`` in this process writes the first
``fraction`` (default one half) of its bytes, flushes them to the file and kills the
process with SIGKILL, which nothing can catch or clean up after. Without the variable
(always, outside tests) a crash point costs one environment lookup.

Sites: ``results-row`` (a row appended to ``results.jsonl``), ``run-log-start`` and
``run-log-end`` (an episode's run MCAP, still under its temporary name, after its static
content and after its last message), ``run-log-written`` (the run MCAP renamed into
place, before its episode's row is recorded).
"""

from __future__ import annotations

import os
import signal
from collections import Counter
from typing import BinaryIO, Final

CRASH_ENV: Final = "SKYVLN_EVAL_CRASH_AT"
SITES: Final = ("results-row", "run-log-start", "run-log-end", "run-log-written")
_passed: Counter[str] = Counter()


def _chosen(site: str) -> float | None:
    """The fraction to write if this write at ``site`` is the one to crash in, else None."""
    spec = os.environ.get(CRASH_ENV)
    if not spec:
        return None
    parts = spec.split(":")
    if len(parts) not in (2, 3) or parts[0] not in SITES:
        raise ValueError(f"${CRASH_ENV}={spec!r}: expected <site>:<n>[:<fraction>] ({SITES})")
    if parts[0] != site:
        return None
    _passed[site] += 1
    if _passed[site] != int(parts[1]):
        return None
    return float(parts[2]) if len(parts) == 3 else 0.5


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def write_or_crash(site: str, handle: BinaryIO, data: bytes) -> None:
    """``handle.write(data)``; at the chosen write, only part of it, then SIGKILL."""
    fraction = _chosen(site)
    if fraction is not None:
        handle.write(data[: int(len(data) * fraction)])
        handle.flush()
        _die()
    handle.write(data)


def crash_point(site: str) -> None:
    """SIGKILL here if this is the chosen pass through ``site``."""
    if _chosen(site) is not None:
        _die()
