"""A response cache in SQLite, keyed by everything that can change the answer.

The key hashes, in this order, the backend identity (backend name, model, server URL:
the model identity first), every decoding parameter, and the messages with their images
by content hash. One model's answers can therefore never be served for another's, and a
change of temperature, seed or schema misses.

A broken cache never breaks a run: an unreadable entry is logged, ignored and later
overwritten; a file that is not a usable database is moved aside (``*.broken-N``) and a
new one started; any SQLite error at run time is logged and counts as a miss. Values
carry a checksum so a corrupted row is detected rather than served.
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


def _checksum(payload: str) -> str:
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


class ResponseCache:
    """SQLite-backed cache of completions, safe to share between threads."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._conn: sqlite3.Connection | None = None
        try:
            self._conn = self._open()
        except sqlite3.Error as error:
            aside = self._move_aside()
            log.warning("LLM cache %s is unusable (%s); moved to %s", self.path, error, aside)
            try:
                self._conn = self._open()
            except sqlite3.Error as again:  # e.g. a read-only folder: run without a cache
                log.error("LLM cache %s cannot be created (%s); caching is off", self.path, again)

    def _open(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(self.path, check_same_thread=False, timeout=30.0)
        try:
            conn.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            conn.execute(
                "CREATE TABLE IF NOT EXISTS responses (key TEXT PRIMARY KEY, backend TEXT, "
                "model TEXT, payload TEXT, checksum TEXT, created_s REAL)"
            )
            found = dict(conn.execute("SELECT key, value FROM meta").fetchall())
            if not found:
                conn.executemany(
                    "INSERT INTO meta VALUES (?, ?)",
                    [("format", CACHE_FORMAT), ("version", str(CACHE_VERSION))],
                )
            elif found.get("format") != CACHE_FORMAT or found.get("version") != str(CACHE_VERSION):
                raise sqlite3.DatabaseError(
                    f"format {found.get('format')!r} version {found.get('version')!r}, "
                    f"expected {CACHE_FORMAT!r} version {CACHE_VERSION}"
                )
            conn.commit()
        except sqlite3.Error:
            conn.close()
            raise
        return conn

    def _move_aside(self) -> Path:
        n = 0
        while (aside := self.path.with_name(f"{self.path.name}.broken-{n}")).exists():
            n += 1
        if self.path.exists():
            self.path.replace(aside)
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
            values = {name: data[name] for name in _FIELDS}
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
        payload = json.dumps({name: getattr(completion, name) for name in _FIELDS})
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
                self._conn.commit()
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
