"""C source compiled at run time to shared libraries cached on disk (solvers, the ray march).

A library's file name carries a key that hashes everything that can change the compiled
code (the caller adds its own parts: source, flags, versions), so a changed input is a new
file and never a stale one. Processes that need the same library at once take a file lock
(:func:`build_lock`): one builds, the others then load its result. A library is written
under a temporary name and renamed into place, so no process ever sees half a file.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from skyvln_eval.paths import cache_root

log = logging.getLogger(__name__)


def compiler() -> str | None:
    """The C compiler to use (``$CC``, else ``gcc``), or ``None`` if there is none."""
    return shutil.which(os.environ.get("CC", "gcc"))


@functools.lru_cache(maxsize=4)
def compiler_identity(cc: str) -> str:
    """The compiler's path and the first line of its ``--version`` (part of cache keys)."""
    try:
        done = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False)
        first = done.stdout.splitlines()[0] if done.stdout else ""
    except OSError:
        first = ""
    return f"{cc} {first}".strip()


def digest(parts: Iterable[str], length: int = 20) -> str:
    """A short hex key over ``parts`` (each one delimited, so no two lists collide)."""
    hashed = hashlib.sha256()
    for part in parts:
        hashed.update(part.encode() + b"\0")
    return hashed.hexdigest()[:length]


@contextmanager
def build_lock(library: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``library``'s lock file (waits while another process builds)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # not a POSIX system: no lock, at worst two processes both build
        yield
        return
    with library.with_suffix(".lock").open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def compile_library(
    name: str,
    text: str,
    cc: str,
    flags: Sequence[str],
    library: Path,
    link: Sequence[str] = (),
) -> None:
    """Compile the C ``text`` (written as ``name.c``) to ``library``: built under a
    temporary name beside it, then renamed into place. Raises
    :class:`subprocess.CalledProcessError` (with the compiler's output) if it fails."""
    with tempfile.TemporaryDirectory(dir=library.parent, prefix=".build-") as build:
        source = Path(build) / f"{name}.c"
        source.write_text(text)
        built = Path(build) / library.name
        log.info("compiling %s with %s (once per source and compiler)", name, cc)
        subprocess.run(
            [cc, *flags, "-o", str(built), str(source), *link, "-lm"],
            check=True,
            capture_output=True,
        )
        built.replace(library)


def cached_library(name: str, text: str, cc: str, flags: Sequence[str]) -> Path:
    """The shared library built by ``cc`` from the C ``text`` with ``flags``, under the
    cache's ``native`` folder (named ``name-<key>.so``, the key over the compiler, the flags
    and the source): compiled on first use, while other processes wait for it. Raises
    :class:`subprocess.CalledProcessError` (with the compiler's output) if the build fails."""
    key = digest((compiler_identity(cc), " ".join(flags), text))
    library = cache_root() / "native" / f"{name}-{key}.so"
    with build_lock(library):
        if not library.exists():
            compile_library(name, text, cc, flags, library)
    return library
