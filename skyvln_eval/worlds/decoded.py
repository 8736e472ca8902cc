"""Decoded map rasters, kept on disk once per machine and mapped into every process.

Decoding a map (a TIFF of 2500 x 2000 pixels, its width resize and three PNG layers) takes
0.2-0.3 s, and every worker process of every run met each map anew. The decoded arrays
are stored as ``.npy`` files under the cache (:func:`~skyvln_eval.paths.cache_root`) and
memory-mapped read-only: opening them costs milliseconds, and processes on one machine
share their pages. The entry's name is a hash of each source file's identity (path, size,
modification time, inode), so a changed file is decoded again, and of whatever else the
decoding depends on (``recipe``). An entry is written to a temporary folder and renamed;
when the cache cannot be written, the freshly decoded arrays are used, with one notice.

The cache keeps at most ``$SKYVLN_EVAL_DECODED_MAPS_GIB`` GiB (default 4: the synthetic
dataset's maps take 63 MB each); the entries used least recently go first.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError
from skyvln_eval.fileio import rename_into_place, sha256_bytes
from skyvln_eval.paths import cache_root

DECODED_DIR = "decoded-maps"
#: Changes whenever what an entry holds changes, so that old entries are not read.
ENTRY_VERSION = 1
BUDGET_ENV = "SKYVLN_EVAL_DECODED_MAPS_GIB"
DEFAULT_BUDGET_GIB = 4.0
#: A staging folder this old was left by a process that died while writing it.
_STALE_STAGING_S = 3600.0

Rasters = dict[str, NDArray[Any]]

_warned = threading.Event()


def _identity(path: Path) -> list[Any]:
    stat = path.stat()
    return [str(path.resolve()), stat.st_size, stat.st_mtime_ns, stat.st_ino]


def entry_key(sources: Sequence[Path], recipe: Mapping[str, Any]) -> str:
    """The entry's name: what was read (each file's identity) and how it was decoded."""
    text = json.dumps(
        [ENTRY_VERSION, [_identity(path) for path in sources], recipe],
        sort_keys=True,
        default=repr,
    )
    return sha256_bytes(text.encode("utf-8"))[:32]


def decoded_rasters(
    sources: Sequence[Path],
    recipe: Mapping[str, Any],
    decode: Callable[[], Rasters],
    cache_dir: Path | None = None,
) -> Rasters:
    """The arrays ``decode()`` makes from ``sources``, read-only, from the cache when it
    holds them (``decode`` is then not called).

    When a source cannot be read (missing, say), ``decode()`` runs without the cache, so
    that the error it raises for that file is the one reported.
    """
    budget = budget_bytes()  # a bad setting is reported before any work
    root = cache_dir or cache_root() / DECODED_DIR
    try:
        folder = root / entry_key(sources, recipe)
    except OSError:
        return decode()
    cached = _read_entry(folder)
    if cached is not None:
        return cached
    rasters = decode()
    try:
        _write_entry(folder, rasters)
        _evict(root, budget, keep=folder)
    except OSError as error:
        if not _warned.is_set():
            _warned.set()
            warnings.warn(
                f"decoded maps are not cached ({error}); every process decodes them again",
                RuntimeWarning,
                stacklevel=2,
            )
        return rasters
    read = _read_entry(folder)
    return rasters if read is None else read


def budget_bytes() -> int:
    """The cache's size limit, from ``$SKYVLN_EVAL_DECODED_MAPS_GIB``."""
    text = os.environ.get(BUDGET_ENV, "")
    try:
        gib = float(text) if text else DEFAULT_BUDGET_GIB
    except ValueError:
        gib = -1.0
    if not gib >= 0.0:
        raise ConfigError(f"${BUDGET_ENV} must be a number of GiB >= 0, got {text!r}")
    return int(gib * 2**30)


def _read_entry(folder: Path) -> Rasters | None:
    names_file = folder / "names.json"
    try:
        names = json.loads(names_file.read_text(encoding="utf-8"))
        # A view as a plain ndarray (it keeps the mapping open); memmap's own subclass
        # would follow into every result computed from it.
        rasters = {
            name: np.load(folder / f"{name}.npy", mmap_mode="r").view(np.ndarray) for name in names
        }
    except (OSError, ValueError):  # not there, evicted meanwhile, or unreadable: a miss
        return None
    with contextlib.suppress(OSError):  # a cache others filled may be read-only to us
        os.utime(names_file)  # used now: evicted last
    return rasters


def _write_entry(folder: Path, rasters: Rasters) -> None:
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        for name, array in rasters.items():
            np.save(staging / f"{name}.npy", np.ascontiguousarray(array), allow_pickle=False)
        # Written last: an entry without it is incomplete and is never read.
        (staging / "names.json").write_text(json.dumps(sorted(rasters)), encoding="utf-8")
        rename_into_place(staging, folder, lambda entry: (entry / "names.json").is_file())
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


def _evict(root: Path, budget: int, keep: Path) -> None:
    """Delete the least recently used entries until the cache fits ``budget`` (never
    ``keep``, just written), and staging folders left by processes that died."""
    now = time.time()
    entries = []
    for folder in root.iterdir():
        try:
            if folder.name.startswith("."):
                if now - folder.stat().st_mtime > _STALE_STAGING_S:
                    shutil.rmtree(folder, ignore_errors=True)
                continue
            used = (folder / "names.json").stat().st_mtime
            size = sum(path.stat().st_size for path in folder.iterdir())
        except FileNotFoundError:  # deleted meanwhile by another process
            continue
        entries.append((used, folder, size))
    total = sum(size for _, _, size in entries)
    for _, folder, size in sorted(entries):
        if total <= budget:
            break
        if folder != keep:
            shutil.rmtree(folder, ignore_errors=True)  # mapped copies stay valid (POSIX)
            total -= size
