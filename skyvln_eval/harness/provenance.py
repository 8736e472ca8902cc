"""Where a run came from: toolkit and library versions and the source's git revision.

Every run directory keeps in ``versions.json`` the provenance of each launch that made
rows with other code than the last one did (a resume after a ``git pull``), with how many
rows it held then, so that any table row can be traced to the exact code that made it;
while more than one version made the rows, every launch warns that its scores mix them.
"""

from __future__ import annotations

import json
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


VERSIONS_FORMAT = "skyvln-eval.versions"
VERSIONS_VERSION = 2


def record_launch(path: Path, rows_before: int) -> None:
    """Add this launch's provenance to the run's ``versions.json`` at ``path`` when it
    differs from the last launch's (called by a launch that will make rows)."""
    from skyvln_eval.fileio import atomic_write_json

    # With no row yet, the launches before made none: the history starts anew.
    launches = _launches(path) if rows_before else []
    current = provenance()
    last = launches[-1] if launches else None
    if last is not None and {k: v for k, v in last.items() if k != "rows_before"} == current:
        return
    launches.append({"rows_before": rows_before, **current})
    atomic_write_json(
        path,
        {"format": VERSIONS_FORMAT, "version": VERSIONS_VERSION, "launches": launches},
        indent=1,
    )


def mixed_versions_note(path: Path) -> str | None:
    """A warning, at every launch, while the run's rows were made by more than one version
    of the code or libraries (``versions.json`` lists a launch per version that made rows;
    an older run's file, one provenance, counts as one)."""
    launches = _launches(path)
    if len(launches) < 2:
        return None
    described = "; ".join(
        f"{_describe(launch)} from row {launch.get('rows_before') or 0}" for launch in launches
    )
    return (
        f"WARNING: this run's rows were made by {len(launches)} versions of the code or "
        f"libraries ({described}): its scores mix them ({path.name} lists each). For one "
        "version, run again into a new run directory."
    )


def _describe(launch: dict[str, Any]) -> str:
    git = launch.get("git")
    if isinstance(git, dict) and git.get("commit"):
        return f"commit {str(git['commit'])[:10]}{' with changes' if git.get('dirty') else ''}"
    return f"skyvln-eval {launch.get('skyvln_eval')}"


def _launches(path: Path) -> list[dict[str, Any]]:
    """The launches recorded so far; a ``versions.json`` of an older run (one provenance,
    written anew at each launch) is its last launch, its row count then unknown."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return []
    except (OSError, ValueError):
        return []  # unreadable: this launch's provenance replaces it
    if isinstance(data, dict) and data.get("format") == VERSIONS_FORMAT:
        launches = data.get("launches")
        return [x for x in launches if isinstance(x, dict)] if isinstance(launches, list) else []
    return [{"rows_before": None, **data}] if isinstance(data, dict) else []
