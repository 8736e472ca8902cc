"""Running the `rerun` executable and the `skyvln-eval` command from the viewer tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from skyvln_eval.viewer.privacy import rerun_environment
from tests.conftest import REPO


def rerun_tool(cli: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``rerun ARGS...`` as the toolkit starts it (analytics off); never raises on failure."""
    return subprocess.run(
        [str(cli), *args],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
        env=rerun_environment(),
        check=False,
    )


def skyvln_eval_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "skyvln_eval.cli", *args]


def run_skyvln_eval(*args: str) -> subprocess.CompletedProcess[str]:
    """``skyvln-eval ARGS...`` in a fresh interpreter, as a user runs it."""
    return subprocess.run(
        skyvln_eval_command(*args),
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=180,
        check=False,
    )
