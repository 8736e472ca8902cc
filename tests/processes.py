"""The process tree as Linux's /proc shows it, for tests of what a command leaves running."""

from __future__ import annotations

import os
import signal
from pathlib import Path


def as_a_terminal_job() -> None:
    """``preexec_fn`` of a command started as a terminal starts one: Ctrl-C acts (a test
    run started in the background, as CI scripts often are, ignores SIGINT, and a child
    would inherit that and never see the signal), and the command has a process group of
    its own, which a terminal's Ctrl-C reaches as a whole."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    os.setsid()


def _state_and_parent(pid_dir: Path) -> tuple[str, int] | None:
    try:
        state, parent = (pid_dir / "stat").read_text().rsplit(")", 1)[1].split()[:2]
    except (OSError, ValueError):
        return None
    return state, int(parent)


def children(pid: int) -> list[int]:
    """Processes whose parent is ``pid``, zombies left out."""
    found = []
    for pid_dir in Path("/proc").glob("[0-9]*"):
        known = _state_and_parent(pid_dir)
        if known is not None and known[1] == pid and known[0] != "Z":
            found.append(int(pid_dir.name))
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie has ended; only its parent's reaping is left)."""
    known = _state_and_parent(Path(f"/proc/{pid}"))
    return known is not None and known[0] != "Z"


def still_alive_after(pids: list[int], seconds: float) -> list[int]:
    """Those of ``pids`` still running once all have ended or ``seconds`` have passed."""
    import time

    deadline = time.monotonic() + seconds
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return [pid for pid in pids if alive(pid)]
