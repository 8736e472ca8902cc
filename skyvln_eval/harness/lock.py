"""One process at a time in a run directory: an OS file lock that dies with its process.

A run locks ``run.lock`` in its directory (``fcntl.flock``, exclusive) before it reads
what is already done and holds it until it has recorded its last episode. The kernel
drops the lock when the process ends, however it ends (even ``kill -9``), so a killed
run never leaves a stale lock behind; the file's content (pid, command, start time,
host) only names the holder in the message a second launch gets. A second launch on the
same directory therefore refuses at once instead of running every episode again.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import shlex
import socket
import sys
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import IO, Any

from skyvln_eval.errors import RunDirBusyError
from skyvln_eval.fileio import ensure_directory

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX (Windows): runs are not locked there
    fcntl = None  # type: ignore[assignment]

LOCK_FILE = "run.lock"


def _command() -> str:
    """This process's command line as a user typed it (``skyvln-eval run ...``), shortened."""
    argv = list(getattr(sys, "orig_argv", sys.argv))
    if len(argv) > 1 and sys.argv and argv[1] == sys.argv[0] and not argv[1].startswith("-"):
        argv = argv[1:]  # a script, e.g. the skyvln-eval console script: its name says it all
    if argv:
        argv[0] = Path(argv[0]).name
    text = " ".join(shlex.join(argv).split())
    return text if len(text) <= 200 else text[:197] + "..."


def _holder_text() -> str:
    return json.dumps(
        {
            "pid": os.getpid(),
            "command": _command(),
            "started": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "host": socket.gethostname(),
        }
    )


def _read_holder(handle: IO[bytes]) -> dict[str, Any]:
    handle.seek(0)
    try:
        data = json.loads(handle.read().decode("utf-8"))
    except (ValueError, UnicodeDecodeError):  # being written by the holder just now
        return {}
    return data if isinstance(data, dict) else {}


class RunDirLock:
    """``with RunDirLock(run_dir):`` holds the run directory or raises
    :class:`~skyvln_eval.errors.RunDirBusyError` naming the process that does."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / LOCK_FILE
        self._handle: IO[bytes] | None = None

    @property
    def held(self) -> bool:
        return self._handle is not None

    def acquire(self) -> None:
        if self._handle is not None or fcntl is None:
            return
        handle = self.path.open("a+b")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(handle)
            handle.close()
            raise RunDirBusyError(str(self.path.parent), holder) from None
        except BaseException:
            handle.close()
            raise
        handle.truncate(0)
        handle.write(_holder_text().encode("utf-8"))
        handle.flush()
        self._handle = handle

    def release(self) -> None:
        if self._handle is None:
            return
        handle, self._handle = self._handle, None
        try:
            handle.truncate(0)  # the next reader must not take us for a holder
        finally:
            handle.close()  # closing the file drops the lock

    def __enter__(self) -> RunDirLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def hold_run_dir(run_dir: str | Path) -> RunDirLock:
    """Create the run directory if needed and lock it (see :class:`RunDirLock`)."""
    lock = RunDirLock(ensure_directory(run_dir, "run directory"))
    lock.acquire()
    return lock


#: A temporary file of :func:`~skyvln_eval.fileio.atomic_write_bytes` and the MCAP
#: writer: ``tempfile.mkstemp(prefix=".<name>.", suffix=".tmp")``, 8 random characters.
_TEMPORARY = re.compile(r"^\.(?P<target>.+)\.[a-z0-9_]{8}\.tmp$")


def leftover_temporaries(
    run_dir: str | Path, top_level: Collection[str], folders: Mapping[str, Collection[str]]
) -> list[Path]:
    """The temporary files that writers killed before their rename left in the run
    directory.

    Only the run's own: at the top, those of the files in ``top_level``; under each
    folder of ``folders`` (any depth), those of files with one of its suffixes. A run
    directory may be a folder that holds other things (``--out .``): a file that merely
    looks temporary is not the run's.
    """
    run_dir = Path(run_dir)
    leftovers = [p for p in run_dir.glob(".*.tmp") if _target(p) in top_level]
    for folder, suffixes in folders.items():
        leftovers += [
            p
            for p in (run_dir / folder).rglob(".*.tmp")
            if (target := _target(p)) is not None and Path(target).suffix in suffixes
        ]
    return sorted(leftovers)


def remove_leftover_temporaries(
    run_dir: str | Path, top_level: Collection[str], folders: Mapping[str, Collection[str]]
) -> int:
    """Delete the :func:`leftover_temporaries`; only the lock's holder may. Returns how many."""
    removed = 0
    for leftover in leftover_temporaries(run_dir, top_level, folders):
        if leftover.is_file():
            leftover.unlink(missing_ok=True)
            removed += 1
    return removed


def _target(path: Path) -> str | None:
    """The name of the file a temporary file was to become, if it is a writer's."""
    match = _TEMPORARY.match(path.name)
    return None if match is None else match["target"]
