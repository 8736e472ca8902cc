"""Bounds of settings shared by the command line and the config files (no imports: the
CLI reads them when it is built, and ``skyvln-eval --help`` stays fast)."""

from __future__ import annotations

from typing import Final

#: The largest bootstrap seed: the seed is kept in an int64 column of ``summary.csv``
#: (a larger one was an OverflowError there; numpy refuses a negative one).
MAX_BOOTSTRAP_SEED: Final = 2**63 - 1
#: The most bootstrap resamples: each is one row of floats per metric in memory (a million
#: is about 0.2 GB for a summary; far more was numpy's "Maximum allowed dimension").
MAX_BOOTSTRAP_RESAMPLES: Final = 1_000_000
#: The most parallel episodes a run (or a reproduction) takes.
MAX_WORKERS: Final = 256
#: The most episodes a worker process runs in threads at once.
MAX_THREADS_PER_WORKER: Final = 64
