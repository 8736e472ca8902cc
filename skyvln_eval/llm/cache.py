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
busy or unwritable is left as it is and this process runs without it.
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


class ResponseCache:
    """SQLite-backed cache of completions, safe to share between threads."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._conn: sqlite3.Connection | None = None
        try:
            self._conn = self._open_when_free()
        except (_NotOurCache, sqlite3.DatabaseError) as error:
            if _corrupt(error):
                self._conn = self._repair(error)
            else:  # busy, read-only, I/O: not the file's fault, so it is left alone
                log.error("LLM cache %s cannot be opened (%s); caching is off", self.path, error)

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
            found = dict(conn.execute("SELECT key, value FROM meta").fetchall())
            conn.execute("COMMIT")
            if found.get("format") != CACHE_FORMAT or found.get("version") != str(CACHE_VERSION):
                raise _NotOurCache(
                    f"format {found.get('format')!r} version {found.get('version')!r}, "
                    f"expected {CACHE_FORMAT!r} version {CACHE_VERSION}"
                )
        except BaseException:
            conn.close()
            raise
        return conn

    def _repair(self, error: BaseException) -> sqlite3.Connection | None:
        """Open again under the OS lock; move the file aside only if it is still corrupt."""
        with exclusive_lock(self.path.with_name(self.path.name + ".lock")):
            try:
                return self._open()  # another process may have repaired it meanwhile
            except (_NotOurCache, sqlite3.DatabaseError) as again:
                if not _corrupt(again):
                    log.error(
                        "LLM cache %s cannot be opened (%s); caching is off", self.path, again
                    )
                    return None
            aside = self._move_aside()
            log.warning("LLM cache %s is unusable (%s); moved to %s", self.path, error, aside)
            try:
                return self._open()
            except sqlite3.Error as fresh:  # e.g. a read-only folder: run without a cache
                log.error("LLM cache %s cannot be created (%s); caching is off", self.path, fresh)
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
        """Store ``completion`` under ``key`` (replacing any corrupt entry); never raises."""
        if self._conn is None:
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
