"""A task function whose module kills any other process that imports it while
``$DIES_IN_WORKERS_PARENT`` names the parent: a worker that dies while starting up,
before it runs an episode (for the executors' tests)."""

from __future__ import annotations

import os

PARENT_ENV = "DIES_IN_WORKERS_PARENT"

if os.environ.get(PARENT_ENV, str(os.getpid())) != str(os.getpid()):
    os._exit(3)  # a worker unpickling the task function


def identity(x: int) -> int:
    return x
