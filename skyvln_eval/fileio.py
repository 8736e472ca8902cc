"""Small file helpers: atomic writes, content hashes, and reading a YAML settings file.

Files (and cache folders) are written to a temporary name in the same directory and
renamed into place, so an interrupted write never leaves a half file under the final name.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

from skyvln_eval.errors import ConfigError


@functools.cache
def _umask() -> int:
    """The process's umask, read once (reading it means setting it: not on every write,
    where another thread's file could be created in between)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def usual_permissions(path: str | Path) -> None:
    """Give a file made by ``tempfile.mkstemp`` (0600) the permissions of one made by
    ``open`` (0666 minus the umask), before it is renamed into place."""
    Path(path).chmod(0o666 & ~_umask())


def atomic_write_bytes(path: str | Path, data: bytes, durable: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename).

    The file gets the usual permissions (0666 minus the umask), not the 0600 that
    temporary files are created with. ``durable``: the data and the rename are synced to
    disk before this returns (a power cut then finds the old file or the new one whole);
    for files whose loss loses work, e.g. a run's results rewritten.
    """
    path = Path(path)
    if path.is_dir():  # else the rename names the temporary file: ".x.abc.tmp: Is a directory"
        raise IsADirectoryError(errno.EISDIR, "a folder, not a file: name a file", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            if durable:
                handle.flush()
                os.fsync(handle.fileno())
        usual_permissions(tmp)
        Path(tmp).replace(path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    if durable:
        sync_directory(path.parent)


def sync_directory(folder: Path) -> None:
    """Sync a folder's entries (a rename in it), where the platform can."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse fsync on a folder: the rename is as durable as it gets
    finally:
        os.close(fd)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, data: Any, indent: int | None = None) -> None:
    """JSON in insertion order, UTF-8, no NaN, with a trailing newline."""
    atomic_write_text(
        path, json.dumps(data, indent=indent, ensure_ascii=False, allow_nan=False) + "\n"
    )


def ensure_directory(path: str | Path, what: str) -> Path:
    """Create the folder ``path`` (and its parents) unless it exists; a clear
    :class:`ConfigError` (starting with ``what``) when it cannot be a folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(
            f"{what} {path} is an existing file, not a folder: name a folder (it is created "
            "if missing)"
        )
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), path)
        raise ConfigError(
            f"{what} {path} cannot be created: {blocking} is a file, not a folder"
        ) from None
    except OSError as error:
        raise ConfigError(f"{what} {path} cannot be created: {error.strerror or error}") from None
    return path


def ensure_writable_directory(path: str | Path, what: str) -> Path:
    """:func:`ensure_directory`, then a probe file created and deleted there: a folder that
    exists but takes no files (read-only, no permission) fails here, once and clearly,
    not on every file of a batch."""
    path = ensure_directory(path, what)
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as error:
        raise ConfigError(f"{what} {path} cannot take files: {error.strerror or error}") from None
    return path


@contextlib.contextmanager
def exclusive_lock(path: str | Path) -> Iterator[None]:
    """Hold an exclusive OS lock on the file ``path`` (created if missing) for the block.

    Threads and processes alike wait their turn (each opening has its own lock); the
    kernel drops the lock when its process dies, so a killed holder never blocks anyone.
    Off POSIX (no ``fcntl``) there is no lock.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a+b") as handle:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
        yield


def rename_into_place(staging: Path, final: Path, complete: Callable[[Path], bool]) -> None:
    """Rename the fully written folder ``staging`` to ``final``. When another process put a
    complete one there first (``complete(final)``), keep theirs and delete ``staging``."""
    try:
        staging.rename(final)
    except OSError:
        shutil.rmtree(staging, ignore_errors=True)
        if not complete(final):
            raise


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


_YAML_KINDS = {list: "a list", str: "a single string", int: "a number", float: "a number"}


def undecodable_at(raw: bytes, error: UnicodeDecodeError) -> str:
    """Where ``raw`` stopped being UTF-8: the byte, its line and its offset."""
    line = raw.count(b"\n", 0, error.start) + 1
    return f"byte 0x{raw[error.start]:02x} on line {line}, byte offset {error.start}"


def object_with_unique_keys(
    pairs: list[tuple[str, Any]], refuse: Callable[[str], Exception]
) -> dict[str, Any]:
    """A JSON object hook (with ``refuse`` bound by ``functools.partial``) that raises
    ``refuse(key)`` for a key given twice: ``json`` keeps the last of a repeated key
    without a word (``"status": "error", "status": "ok"`` read as ok)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise refuse(key)
        out[key] = value
    return out


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a key given twice in one mapping: YAML keeps the
    last one without a word (``system: a`` then ``system: b`` ran as "b"), where the JSON
    readers here refuse repeated keys. Keys merged in with ``<<`` may still be overridden."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            first_line: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, str | int | float | bool):
                    continue  # not a key a mapping of settings has; PyYAML says what it is
                if key not in first_line:
                    first_line[key] = key_node.start_mark.line + 1
                    continue
                raise yaml.constructor.ConstructorError(
                    "while reading a mapping",
                    node.start_mark,
                    f"found the key {key!r} twice (first on line {first_line[key]}): YAML "
                    "would keep the last one without a word; give it once",
                    key_node.start_mark,
                )
        return super().construct_mapping(node, deep)


def load_yaml(text: str, path: str | Path) -> Any:
    """``yaml.safe_load`` of ``text``, read from ``path``: a syntax error's marks name the
    file (given text, PyYAML names it "<unicode string>"); a key given twice in a mapping,
    or a number Python will not read (an integer of thousands of digits), is a
    ``yaml.YAMLError`` too."""
    loader = _StrictLoader(text)
    loader.name = str(path)
    try:
        return loader.get_single_data()
    except ValueError as error:  # int() refuses more than 4300 digits
        raise yaml.YAMLError(f'in "{path}": a value that cannot be read: {error}') from None
    finally:
        loader.dispose()


def read_yaml_mapping(path: str | Path, what: str) -> dict[str, Any]:
    """The mapping at the top of the YAML file ``path`` (an empty file gives ``{}``).

    Every way the file can be unusable is a :class:`ConfigError` that starts with ``what``
    and the file: unreadable, not UTF-8 (with the line and the offending byte), not YAML
    (with the line), or a top level other than a mapping (saying what it is instead).
    """
    file = Path(path)
    try:
        raw = file.read_bytes()
    except OSError as error:
        raise ConfigError(f"{what} {file}: cannot read it: {error.strerror or error}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        where = undecodable_at(raw, error)
        raise ConfigError(f"{what} {file}: not UTF-8 text ({where}); save it as UTF-8") from None
    try:
        data = load_yaml(text, file)
    except yaml.YAMLError as error:
        raise ConfigError(f"{what} {file}: not valid YAML: {error}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        kind = _YAML_KINDS.get(type(data), type(data).__name__)
        raise ConfigError(
            f"{what} {file}: the top level must be a mapping of settings (key: value lines), "
            f"but it is {kind}"
        )
    return data
