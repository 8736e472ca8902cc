"""Where a run came from: toolkit and library versions and the source's git revision.

Written once into every run directory (``versions.json``) so that any table row can be
traced to the exact code that made it.
"""

from __future__ import annotations

import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import skyvln_eval

LIBRARIES = (
    "numpy",
    "pandas",
    "opencv-python-headless",
    "shapely",
    "networkx",
    "casadi",
    "mcap",
    "openai",
    "ray",
)


def _version(distribution: str) -> str | None:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def git_revision(path: Path | None = None) -> dict[str, Any] | None:
    """``{"commit": ..., "dirty": bool}`` of the git checkout holding the toolkit, if any."""
    source = path or Path(skyvln_eval.__file__).resolve().parent.parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=source,
            capture_output=True,
            text=True,
            check=True,
            timeout=10,
        ).stdout.strip()
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=source,
            capture_output=True,
            text=True,
            check=True,
            timeout=10,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "dirty": bool(status.strip())}


def provenance() -> dict[str, Any]:
    return {
        "skyvln_eval": skyvln_eval.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "libraries": {name: _version(name) for name in LIBRARIES},
        "git": git_revision(),
    }
