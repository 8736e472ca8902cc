"""The result store of a run: one JSON line per (split, episode), appended atomically.

Only the coordinating process writes. Each row is one ``write`` of a complete line,
flushed and fsynced before the next episode is recorded, so a run killed at any moment
(even with SIGKILL) leaves whole rows plus at most one partial last line. Opening the
store again drops that partial line (and says so), and the run resumes with exactly the
episodes that have no row: nothing is lost or duplicated.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from skyvln_eval.errors import FormatVersionError

RESULTS_FILE = "results.jsonl"
ROW_FORMAT = "skyvln-eval/run-row"
ROW_VERSION = 1

RowStatus = Literal["ok", "failed"]
RowKey = tuple[str, str]  # (split, episode_id)


@dataclass(frozen=True)
class StoredRow:
    """One stored row: the episode key, its status, and the result or the error."""

    split: str
    episode_id: str
    status: RowStatus
    result: dict[str, Any] | None = None
    error: dict[str, str] | None = None

    @property
    def key(self) -> RowKey:
        return (self.split, self.episode_id)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": ROW_FORMAT,
            "version": ROW_VERSION,
            "split": self.split,
            "episode_id": self.episode_id,
            "status": self.status,
            "result": self.result,
            "error": self.error,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str) -> StoredRow:
        if data.get("format") != ROW_FORMAT or data.get("version") != ROW_VERSION:
            raise FormatVersionError(
                where,
                data.get("version"),
                ROW_VERSION,
                "This run was written by another version of skyvln-eval; use a new run directory.",
            )
        return cls(
            data["split"], data["episode_id"], data["status"], data.get("result"), data.get("error")
        )


@dataclass
class RecoveryReport:
    """What opening an existing store found: rows kept, a dropped partial line, superseded rows."""

    rows: int = 0
    dropped_partial_bytes: int = 0
    superseded: list[RowKey] = field(default_factory=list)

    def messages(self) -> list[str]:
        out = []
        if self.dropped_partial_bytes:
            out.append(
                f"dropped an incomplete last row ({self.dropped_partial_bytes} bytes) left by an "
                "interrupted run; its episode runs again"
            )
        if self.superseded:
            out.append(f"{len(self.superseded)} episode(s) were run again; their latest rows count")
        return out


class ResultStore:
    """Append-only rows of one run directory; the latest row per (split, episode) counts."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / RESULTS_FILE
        self._rows: dict[RowKey, StoredRow] = {}
        self.recovery = self._load()

    def _load(self) -> RecoveryReport:
        report = RecoveryReport()
        if not self.path.exists():
            return report
        data = self.path.read_bytes()
        complete = data.rfind(b"\n") + 1
        if complete < len(data):
            report.dropped_partial_bytes = len(data) - complete
            with self.path.open("r+b") as handle:
                handle.truncate(complete)
                handle.flush()
                os.fsync(handle.fileno())
        for number, line in enumerate(data[:complete].splitlines(), start=1):
            if not line.strip():
                continue
            row = StoredRow.from_json(json.loads(line), f"{self.path}:{number}")
            if row.key in self._rows:
                report.superseded.append(row.key)
            self._rows[row.key] = row
        report.rows = len(self._rows)
        return report

    def __contains__(self, key: RowKey) -> bool:
        return key in self._rows

    def __len__(self) -> int:
        return len(self._rows)

    def get(self, key: RowKey) -> StoredRow | None:
        return self._rows.get(key)

    def rows(self) -> list[StoredRow]:
        """The latest row of every episode, in the order episodes were first recorded."""
        return list(self._rows.values())

    def append(self, row: StoredRow) -> None:
        """Record one episode durably: a single write of one line, flushed and fsynced."""
        line = (json.dumps(row.to_json(), allow_nan=False, separators=(",", ":")) + "\n").encode()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("ab") as handle:
            handle.write(line)
            handle.flush()
            os.fsync(handle.fileno())
        self._rows[row.key] = row

    def missing(self, keys: Iterable[RowKey], retry_failed: bool = False) -> list[RowKey]:
        """Keys without a row (or, with ``retry_failed``, whose row is a failure), in order."""
        out = []
        for key in keys:
            row = self._rows.get(key)
            if row is None or (retry_failed and row.status == "failed"):
                out.append(key)
        return out
