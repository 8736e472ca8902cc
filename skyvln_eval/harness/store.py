"""The result store of a run: ``results.jsonl``, one :class:`EpisodeResult` per line.

The file is a results file of :mod:`skyvln_eval.metrics.results_io` (a header line, then
one row per episode), so ``skyvln-eval score RUN_DIR/results.jsonl`` scores a run, even
one still in progress. Only the coordinating process writes. Each row is one ``write`` of
a complete line, flushed and fsynced before the next episode is recorded, so a run killed
at any moment (even with SIGKILL) leaves whole rows plus at most one partial last line.
Opening the store again drops that partial line (and says so), and the run resumes with
exactly the episodes that have no row: nothing is lost or duplicated.

An episode run again (``retry_failed``) appends a new row; on the next opening the file is
compacted to the latest row per episode, so it never holds duplicates for long.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from skyvln_eval.errors import FormatVersionError
from skyvln_eval.fileio import atomic_write_bytes
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.results_io import (
    RESULTS_FORMAT,
    RESULTS_VERSION,
    result_from_json_dict,
    result_to_json_dict,
)

RESULTS_FILE = "results.jsonl"
RowKey = tuple[str, str]  # (split, episode_id)
HEADER = {"format": RESULTS_FORMAT, "version": RESULTS_VERSION}


def _line(data: dict[str, object]) -> bytes:
    return (json.dumps(data, allow_nan=False, separators=(",", ":")) + "\n").encode("utf-8")


def key_of(result: EpisodeResult) -> RowKey:
    return (result.split, result.episode_id)


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
    """Append-only episode results of one run directory; the latest row per episode counts."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / RESULTS_FILE
        self._rows: dict[RowKey, EpisodeResult] = {}
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
        lines = data[:complete].splitlines()
        if not lines:
            return report
        header = json.loads(lines[0])
        if not isinstance(header, dict) or header.get("format") != RESULTS_FORMAT:
            raise FormatVersionError(
                str(self.path), header, HEADER, "This is not a run's results file."
            )
        if header.get("version") != RESULTS_VERSION:
            raise FormatVersionError(
                str(self.path),
                header.get("version"),
                RESULTS_VERSION,
                "The run was written by another version of skyvln-eval; use a new run directory.",
            )
        for number, line in enumerate(lines[1:], start=1):
            if line.strip():
                result = result_from_json_dict(json.loads(line), str(self.path), number)
                if key_of(result) in self._rows:
                    report.superseded.append(key_of(result))
                self._rows[key_of(result)] = result
        if report.superseded:
            self._rewrite()
        report.rows = len(self._rows)
        return report

    def _rewrite(self) -> None:
        body = b"".join(_line(result_to_json_dict(r)) for r in self._rows.values())
        atomic_write_bytes(self.path, _line(HEADER) + body)

    def __contains__(self, key: RowKey) -> bool:
        return key in self._rows

    def __len__(self) -> int:
        return len(self._rows)

    def get(self, key: RowKey) -> EpisodeResult | None:
        return self._rows.get(key)

    def results(self) -> list[EpisodeResult]:
        """The latest result of every episode, by (split, episode id): the file holds them
        in the order they finished, which depends on the workers."""
        return [self._rows[key] for key in sorted(self._rows)]

    def append(self, result: EpisodeResult) -> None:
        """Record one episode durably: a single write of whole lines, flushed and fsynced."""
        line = _line(result_to_json_dict(result))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new_file = not self.path.exists() or self.path.stat().st_size == 0
        with self.path.open("ab") as handle:
            handle.write(_line(HEADER) + line if new_file else line)
            handle.flush()
            os.fsync(handle.fileno())
        self._rows[key_of(result)] = result

    def missing(self, keys: Iterable[RowKey], retry_failed: bool = False) -> list[RowKey]:
        """Keys without a row (or, with ``retry_failed``, whose row is an error), in order."""
        out = []
        for key in keys:
            row = self._rows.get(key)
            if row is None or (retry_failed and row.status == "error"):
                out.append(key)
        return out
