"""Where the toolkit keeps generated files it can rebuild: datasets, compiled solvers."""

from __future__ import annotations

import os
from pathlib import Path


def cache_root() -> Path:
    """``$SKYVLN_EVAL_CACHE``, else ``$XDG_CACHE_HOME/skyvln-eval``, else ``~/.cache/skyvln-eval``.

    Everything under it can be deleted; it is rebuilt on use.
    """
    if env := os.environ.get("SKYVLN_EVAL_CACHE"):
        return Path(env)
    if xdg := os.environ.get("XDG_CACHE_HOME"):
        return Path(xdg) / "skyvln-eval"
    return Path.home() / ".cache" / "skyvln-eval"
