"""A response cache in SQLite, keyed by everything that can change the answer.

The key hashes, in this order, the backend identity (backend name, model, server URL:
the model identity first), every decoding parameter, and the messages with their images
by content hash. One model's answers can therefore never be served for another's, and a
change of temperature, seed or schema misses.

A broken cache never breaks a run: an unreadable entry is logged, ignored and later
overwritten; a file that is really corrupt (not a database, a damaged image, another
format) is moved aside (``*.broken-N``) and a new one started; any SQLite error at run
time is logged and counts as a miss. Values carry a checksum so a corrupted row is
detected rather than served.

Many threads and processes may open (and create) one cache at the same moment: it runs
in WAL mode with a busy timeout, the schema and format record are created if absent in
one ``BEGIN IMMEDIATE`` transaction, and the decision to move a file aside is taken under
an OS lock on ``<cache>.lock``, after opening again, so that a database another process
has just created (or repaired) is never mistaken for a corrupt one. A cache that is only
busy or unwritable is left as it is. This process then reads it without writing (a
read-only file, folder or file system: its answers are served, new ones not stored;
said once per file, and :attr:`ResponseCache.read_only`), or runs without it when even
that fails (:attr:`ResponseCache.problem` says why).
"""

from __future__ import annotations

import hashlib
import json
import logging
import sqlite3
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from skyvln_eval.fileio import exclusive_lock
from skyvln_eval.llm.types import Completion, GenerationConfig, Message

log = logging.getLogger(__name__)

CACHE_FORMAT: Final = "skyvln-eval/llm-cache"
CACHE_VERSION: Final = 2
_FIELDS: Final = (
    "text",
    "backend",
    "model",
    "prompt_tokens",
    "completion_tokens",
    "latency_s",
    "finish_reason",
    "structured_output",
)
#: Fields added since the first cache format, all tuples (entries written before have
#: none: empty).
_LATER_FIELDS: Final = ("server_defaults",)
#: Counts added since, optional (entries written before have none: unknown).
_LATER_COUNTS: Final = ("cached_prompt_tokens", "reasoning_tokens")


def cache_key(
    identity: Mapping[str, Any], messages: Sequence[Message], config: GenerationConfig
) -> str:
    """SHA-256 of the canonical JSON of (identity, decoding parameters, messages)."""
    material = {
        "identity": dict(identity),
        "config": config.key_material(),
        "messages": [m.fingerprint() for m in messages],
    }
    canonical = json.dumps(material, sort_keys=True, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


#: Seconds a connection waits for another's write before giving up (SQLite busy timeout).
BUSY_TIMEOUT_S: Final = 30.0
#: SQLite result codes that mean another connection holds the file for now.
_BUSY_CODES: Final = frozenset({sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED})
#: SQLite result codes that mean the file itself is damaged, not merely busy or unwritable.
_CORRUPT_CODES: Final = frozenset({sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB})


class _NotOurCache(Exception):
    """The database is sound but holds another format or version."""


def _corrupt(error: BaseException) -> bool:
    if isinstance(error, _NotOurCache):
        return True
    code = getattr(error, "sqlite_errorcode", None)
    return code is not None and (code & 0xFF) in _CORRUPT_CODES


def _checksum(payload: str) -> str:
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


def _check_format(conn: sqlite3.Connection) -> None:
    """Raise :class:`_NotOurCache` unless ``conn``'s meta table names this format and version."""
    found = dict(conn.execute("SELECT key, value FROM meta").fetchall())
    if found.get("format") != CACHE_FORMAT or found.get("version") != str(CACHE_VERSION):
        raise _NotOurCache(
            f"format {found.get('format')!r} version {found.get('version')!r}, "
            f"expected {CACHE_FORMAT!r} version {CACHE_VERSION}"
        )


def resolve_cache_path(cache_path: str, out_dir: str | Path) -> str:
    """Where ``cache_path`` is: a relative path is taken inside the output folder
    ``out_dir`` (a run's ``--out``, a plan's), with everything else the run writes, not in
    the working directory; an absolute one is kept. The one rule for runs and plans."""
    return cache_path if Path(cache_path).is_absolute() else str(Path(out_dir) / cache_path)


#: What was said of which cache in this process (read-only, caching off): said once,
#: not once per client (a run builds one per episode).
_told: set[tuple[Path, str]] = set()
_told_lock = threading.Lock()


def _first_time(path: Path, what: str) -> bool:
    """Whether ``what`` is said of the cache at ``path`` for the first time here."""
    key = (path.resolve(), what)
    with _told_lock:
        told = key in _told
        _told.add(key)
    return not told


class ResponseCache:
    """SQLite-backed cache of completions, safe to share between threads."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._conn: sqlite3.Connection | None = None
        #: Answers are read from the file but not stored (it cannot be written).
        self.read_only = False
        #: Why the cache cannot be written (read-only) or used at all (``usable`` false).
        self.problem: str | None = None
        try:
            self._conn = self._open_when_free()
        except (_NotOurCache, sqlite3.DatabaseError, OSError) as error:  # OSError: no folder
            if _corrupt(error):
                try:
                    self._conn = self._repair(error)
                except OSError as unrepaired:  # no lock nor rename in a read-only folder
                    self._conn = self._open_for_reading(error, unrepaired)
            else:  # busy, read-only, I/O: not the file's fault, so it is left alone
                self._conn = self._open_for_reading(error)

    def _open_when_free(self) -> sqlite3.Connection:
        """:meth:`_open`, tried again while another connection holds the file: switching
        to WAL can meet a lock the busy handler does not wait for."""
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        delay = 0.01
        while True:
            try:
                return self._open()
            except sqlite3.OperationalError as error:
                code = getattr(error, "sqlite_errorcode", None)
                busy = code is not None and (code & 0xFF) in _BUSY_CODES
                if not busy or time.monotonic() + delay > deadline:
                    raise
                time.sleep(delay)
                delay = min(0.5, delay * 2)

    def _open(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # Autocommit (isolation_level=None): transactions are explicit, as below.
        conn = sqlite3.connect(
            self.path, check_same_thread=False, timeout=BUSY_TIMEOUT_S, isolation_level=None
        )
        try:
            conn.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
            conn.execute("PRAGMA journal_mode = WAL")
            # A cache may lose its last answers in a power cut (never its consistency): no
            # fsync per answer, only at checkpoints.
            conn.execute("PRAGMA synchronous = NORMAL")
            conn.execute("BEGIN IMMEDIATE")  # one writer sets the schema up; others wait
            conn.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            conn.execute(
                "CREATE TABLE IF NOT EXISTS responses (key TEXT PRIMARY KEY, backend TEXT, "
                "model TEXT, payload TEXT, checksum TEXT, created_s REAL)"
            )
            conn.executemany(
                "INSERT OR IGNORE INTO meta VALUES (?, ?)",
                [("format", CACHE_FORMAT), ("version", str(CACHE_VERSION))],
            )
            conn.execute("COMMIT")
            _check_format(conn)
        except BaseException:
            conn.close()
            raise
        return conn

    def _open_read_only(self) -> sqlite3.Connection:
        """The file opened for reading only (``mode=ro``, never created). A WAL database
        also needs its ``-shm`` index, which a read-only folder cannot hold: it is then read
        as ``immutable`` (without locks: on a read-only file system no one else writes it),
        unless a ``-wal`` file exists, whose answers that would not see."""
        uri = self.path.resolve().as_uri()
        try:
            return self._connect_for_reading(f"{uri}?mode=ro")
        except sqlite3.Error:
            if self.path.with_name(self.path.name + "-wal").exists():
                raise
        return self._connect_for_reading(f"{uri}?mode=ro&immutable=1")

    @staticmethod
    def _connect_for_reading(uri: str) -> sqlite3.Connection:
        conn = sqlite3.connect(
            uri, uri=True, check_same_thread=False, timeout=BUSY_TIMEOUT_S, isolation_level=None
        )
        try:
            _check_format(conn)  # the first read opens the file
        except BaseException:
            conn.close()
            raise
        return conn

    def _open_for_reading(
        self, error: BaseException, also: BaseException | None = None
    ) -> sqlite3.Connection | None:
        """After ``error`` (and ``also``) kept the cache from being opened for writing: the
        cache read-only, its answers served but new ones not stored, or ``None`` (caching
        off) when it cannot even be read."""
        reason = str(error) + (f"; {also}" if also is not None else "")
        try:
            conn = self._open_read_only()
        except (_NotOurCache, sqlite3.Error) as unread:
            self.problem = f"{reason}; read-only too: {unread}"
            if _first_time(self.path, "off"):
                log.error(
                    "LLM cache %s cannot be opened (%s); caching is off", self.path, self.problem
                )
            return None
        self.read_only = True
        self.problem = reason
        if _first_time(self.path, "read-only"):
            log.warning(
                "LLM cache %s cannot be written (%s): it is read-only, its answers are read "
                "from it and new ones are not stored",
                self.path,
                reason,
            )
        return conn

    def _repair(self, error: BaseException) -> sqlite3.Connection | None:
        """Open again under the OS lock; move the file aside only if it is still corrupt."""
        with exclusive_lock(self.path.with_name(self.path.name + ".lock")):
            try:
                return self._open()  # another process may have repaired it meanwhile
            except (_NotOurCache, sqlite3.DatabaseError) as again:
                if not _corrupt(again):
                    return self._open_for_reading(again)
            aside = self._move_aside()
            log.warning("LLM cache %s is unusable (%s); moved to %s", self.path, error, aside)
            try:
                return self._open()
            except sqlite3.Error as fresh:  # e.g. a read-only folder: run without a cache
                self.problem = f"cannot be created: {fresh}"
                if _first_time(self.path, "off"):
                    log.error(
                        "LLM cache %s cannot be created (%s); caching is off", self.path, fresh
                    )
                return None

    def _move_aside(self) -> Path:
        n = 0
        while (aside := self.path.with_name(f"{self.path.name}.broken-{n}")).exists():
            n += 1
        if self.path.exists():
            self.path.replace(aside)
        for suffix in ("-wal", "-shm"):  # WAL companions belong to the file moved aside
            companion = self.path.with_name(self.path.name + suffix)
            if companion.exists():
                companion.replace(aside.with_name(aside.name + suffix))
        return aside

    @property
    def usable(self) -> bool:
        return self._conn is not None

    def get(self, key: str) -> Completion | None:
        """The cached completion for ``key``, or ``None`` (miss, or an unusable entry)."""
        if self._conn is None:
            return None
        try:
            with self._lock:
                row = self._conn.execute(
                    "SELECT payload, checksum FROM responses WHERE key = ?", (key,)
                ).fetchone()
        except sqlite3.Error as error:
            log.warning("LLM cache %s read failed (%s); treated as a miss", self.path, error)
            return None
        if row is None:
            return None
        payload, checksum = row
        try:
            if not isinstance(payload, str) or _checksum(payload) != checksum:
                raise ValueError("checksum mismatch")
            data = json.loads(payload)
            values: dict[str, Any] = {name: data[name] for name in _FIELDS}
            values |= {name: tuple(data.get(name, ())) for name in _LATER_FIELDS}
            values |= {name: data.get(name) for name in _LATER_COUNTS}
            return Completion(**values, cached=True)
        except (ValueError, KeyError, TypeError) as error:
            log.warning(
                "LLM cache %s: entry %s is corrupt (%s); ignored", self.path, key[:12], error
            )
            return None

    def put(self, key: str, completion: Completion) -> None:
        """Store ``completion`` under ``key`` (replacing any corrupt entry); never raises.
        A read-only cache stores nothing (it said so when opened)."""
        if self._conn is None or self.read_only:
            return
        payload = json.dumps(
            {name: getattr(completion, name) for name in (*_FIELDS, *_LATER_FIELDS, *_LATER_COUNTS)}
        )
        try:
            with self._lock:
                self._conn.execute(
                    "INSERT OR REPLACE INTO responses VALUES (?, ?, ?, ?, ?, ?)",
                    (
                        key,
                        completion.backend,
                        completion.model,
                        payload,
                        _checksum(payload),
                        time.time(),
                    ),
                )
        except sqlite3.Error as error:
            log.warning("LLM cache %s write failed (%s); answer not cached", self.path, error)

    def __len__(self) -> int:
        if self._conn is None:
            return 0
        with self._lock:
            return int(self._conn.execute("SELECT COUNT(*) FROM responses").fetchone()[0])

    def close(self) -> None:
        if self._conn is not None:
            with self._lock:
                self._conn.close()
            self._conn = None
