"""The result store of a run: ``results.jsonl``, one :class:`EpisodeResult` per line.

The file is a results file of :mod:`skyvln_eval.metrics.results_io` (a header line, then
one row per episode), so ``skyvln-eval score RUN_DIR`` scores a run (one still in progress
with ``--allow-incomplete``). Only the coordinating process writes, under the run
directory's lock (:mod:`.lock`). Each row is one ``write`` of a complete line, flushed and fsynced
before the next episode is recorded, so a run killed at any moment (even with SIGKILL)
leaves whole rows plus at most one partial last line.

Opening the store to resume (``repair=True``) sets every damaged line aside: a partial
last line, a line that is not JSON (a bad disk block, an edit gone wrong) or not a valid
row. Each goes, as found and with its line number and the reason, to
``results.damaged.jsonl`` beside it (never silently dropped), the file is rewritten
without it, and its episode runs again. A row whose episode stopped the run (refused
credentials, a full disk: ``extra["fatal"]``) does not count as done either. Opened to
read only, the store leaves the file as it is and skips what it cannot read.

An episode run again (``retry_failed``) gets its row replaced (the file is rewritten under
a temporary name); a file that holds two rows of an episode all the same (written by an
older version) is compacted to the latest on opening. A write that fails (a full disk)
raises :class:`~skyvln_eval.errors.ResultsWriteError`, after taking the partial line back
off, so every row recorded before stays intact.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from skyvln_eval.errors import DataError, FormatVersionError, ResultRecordError, ResultsWriteError
from skyvln_eval.fileio import atomic_write_bytes, sync_directory
from skyvln_eval.harness.crashpoints import write_or_crash
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.results_io import (
    RESULTS_FORMAT,
    RESULTS_VERSION,
    result_from_json_dict,
    result_to_json_dict,
)

RESULTS_FILE = "results.jsonl"
DAMAGED_FILE = "results.damaged.jsonl"
DAMAGED_FORMAT = "skyvln-eval.damaged-result-rows"
DAMAGED_VERSION = 1
RowKey = tuple[str, str]  # (split, episode_id)
HEADER = {"format": RESULTS_FORMAT, "version": RESULTS_VERSION}
#: Enough of a damaged row to tell which episode it was (rows start with these keys).
_EPISODE_ID = re.compile(rb'"episode_id":\s*"([^"\\]{1,200})"')
_SPLIT = re.compile(rb'"split":\s*"([^"\\]{1,50})"')


def _line(data: dict[str, object]) -> bytes:
    return (json.dumps(data, allow_nan=False, separators=(",", ":")) + "\n").encode("utf-8")


def key_of(result: EpisodeResult) -> RowKey:
    return (result.split, result.episode_id)


@dataclass(frozen=True)
class DamagedRow:
    """A line of ``results.jsonl`` that is not a usable row: where, why, what it held."""

    line: int  # 1-based, the header being line 1
    reason: str
    text: bytes
    episode_id: str | None  # the episode it seems to be of, when enough of it survives
    split: str | None

    @property
    def episode(self) -> str | None:
        if self.episode_id is None:
            return None
        return f"{self.split}/{self.episode_id}" if self.split else self.episode_id

    def is_of(self, key: RowKey) -> bool:
        """Whether it seems to be the row of episode ``key`` (a cut row may lack its split)."""
        return self.episode_id == key[1] and self.split in (None, key[0])

    def to_json(self) -> dict[str, object]:
        return {
            "line": self.line,
            "reason": self.reason,
            "episode": self.episode,
            "text": self.text.decode("utf-8", "backslashreplace"),
        }


@dataclass
class RecoveryReport:
    """What opening an existing store found: rows kept, damaged lines, superseded rows."""

    rows: int = 0
    damaged: list[DamagedRow] = field(default_factory=list)
    superseded: list[RowKey] = field(default_factory=list)
    set_aside_to: Path | None = None
    kept_keys: frozenset[RowKey] = frozenset()
    path: Path | None = None
    max_listed = 20

    @property
    def dropped_partial_bytes(self) -> int:
        """Bytes of an incomplete last row (a write cut short), 0 if there was none."""
        return sum(len(d.text) for d in self.damaged if d.reason.startswith("incomplete last"))

    def _fate(self, row: DamagedRow) -> str:
        if row.episode is None:
            return "its episode runs again"
        if any(row.is_of(key) for key in self.kept_keys):
            return f"episode {row.episode} has another row, which counts"
        return f"episode {row.episode} runs again"

    def why_missing(self, keys: Iterable[RowKey]) -> str:
        """A sentence naming, of ``keys`` (episodes without a usable row), those whose only
        row is damaged, with the file, line and reason, and the damaged lines of no known
        episode, which may be theirs; empty when there are none. Without it a damaged row
        read as an episode never run, its reason only in a separate warning."""
        keys = list(keys)
        theirs = [row for row in self.damaged if any(row.is_of(key) for key in keys)]
        unknown = [row for row in self.damaged if row.episode is None]
        if not theirs and not unknown:
            return ""
        where = self.path if self.path is not None else RESULTS_FILE
        said = []
        if theirs:
            said.append(f"{len({row.episode for row in theirs})} of them have only a damaged row")
        if unknown:
            said.append(f"{len(unknown)} damaged line(s) of no known episode may be theirs")
        shown = [
            f"line {row.line}, {row.episode or 'episode unknown'}: {row.reason}"
            for row in theirs + unknown
        ]
        more = f"; and {len(shown) - 5} more" if len(shown) > 5 else ""
        return (
            f"{' and '.join(said)} in {where}, read past ({'; '.join(shown[:5])}{more}); a "
            "line mended by hand counts again. "
        )

    def messages(self) -> list[str]:
        out = []
        where = self.path.name if self.path is not None else RESULTS_FILE
        aside = (
            f"set aside in {self.set_aside_to}"
            if self.set_aside_to is not None
            else "skipped (the file is left as it is)"
        )
        for row in self.damaged[: self.max_listed]:
            fate = self._fate(row)
            out.append(f"{where} line {row.line}: damaged row ({row.reason}); {aside}; {fate}")
        if len(self.damaged) > self.max_listed:
            out.append(f"... and {len(self.damaged) - self.max_listed} more damaged row(s)")
        if self.superseded:
            out.append(f"{len(self.superseded)} episode(s) were run again; their latest rows count")
        return out


def _damage(line: int, reason: str, text: bytes) -> DamagedRow:
    def found(pattern: re.Pattern[bytes]) -> str | None:
        match = pattern.search(text)
        return None if match is None else match.group(1).decode("utf-8", "replace")

    return DamagedRow(line, reason, text, found(_EPISODE_ID), found(_SPLIT))


def _parse_row(text: bytes, path: Path, line: int) -> EpisodeResult | str:
    """The row on ``line``, or why it is not one."""
    try:
        data = json.loads(text.decode("utf-8"))
    except UnicodeDecodeError as error:
        return f"not UTF-8 text at byte {error.start}"
    except json.JSONDecodeError as error:
        return f"not JSON: {error.msg} (character {error.pos})"
    except (ValueError, RecursionError) as error:
        return f"not usable JSON: {error}"
    try:
        return result_from_json_dict(data, str(path), line - 2, line)
    except ResultRecordError as error:
        issue = error.issue
        return f"not a valid row: {issue.field + ': ' if issue.field else ''}{issue.message}"
    except (DataError, ValueError, TypeError, KeyError) as error:
        return f"not a valid row: {type(error).__name__}: {error}"


class ResultStore:
    """Append-only episode results of one run directory; the latest row per episode counts.

    ``repair``: set damaged lines aside and rewrite the file (only the process that holds
    the run directory's lock may); otherwise read only.
    """

    def __init__(self, run_dir: str | Path, repair: bool = True) -> None:
        self.path = Path(run_dir) / RESULTS_FILE
        self.damaged_path = Path(run_dir) / DAMAGED_FILE
        self._rows: dict[RowKey, EpisodeResult] = {}
        self._lines: dict[RowKey, bytes] = {}
        self.recovery = self._load(repair)

    def _check_header(self, text: bytes) -> bool:
        """True for our header; False for a damaged one; raises for another format's."""
        try:
            header = json.loads(text.decode("utf-8"))
        except (ValueError, UnicodeDecodeError):
            return False
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
        return True

    def _load(self, repair: bool) -> RecoveryReport:
        report = RecoveryReport(path=self.path)
        if not self.path.exists():
            return report
        if not self.path.is_file():
            raise DataError(f"{self.path} is not a file: move it away to resume this run")
        lines = self.path.read_bytes().split(b"\n")
        tail = lines.pop()  # what follows the last line end: a row cut short, or nothing
        if lines and not self._check_header(lines[0]):
            report.damaged.append(_damage(1, "damaged header line", lines[0]))
        for number, text in enumerate(lines[1:], start=2):
            if not text.strip():
                continue
            parsed = _parse_row(text, self.path, number)
            if isinstance(parsed, str):
                report.damaged.append(_damage(number, parsed, text))
                continue
            if key_of(parsed) in self._rows:
                report.superseded.append(key_of(parsed))
            self._rows[key_of(parsed)] = parsed
            self._lines[key_of(parsed)] = text + b"\n"
        if tail:
            reason = "incomplete last row: no line end, a write cut short"
            report.damaged.append(_damage(len(lines) + 1, reason, tail))
        report.rows = len(self._rows)
        report.kept_keys = frozenset(self._rows)
        if repair and (report.damaged or report.superseded):
            if report.damaged:
                self._set_aside(report.damaged)
                report.set_aside_to = self.damaged_path
            self._rewrite()
        return report

    def _set_aside(self, rows: list[DamagedRow]) -> None:
        # Appended and synced before results.jsonl is rewritten without them: killed in
        # between, the rows are set aside again next time (twice in the side file, never lost).
        found = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        head = {"format": DAMAGED_FORMAT, "version": DAMAGED_VERSION, "of": RESULTS_FILE}
        body = b"".join(_line(row.to_json() | {"set_aside": found}) for row in rows)
        with self.damaged_path.open("a+b") as handle:
            size = handle.seek(0, os.SEEK_END)
            if size:  # a line cut short by a kill mid-append ends here: not joined to ours
                handle.seek(size - 1)
                torn = handle.read(1) != b"\n"
                start = b"\n" if torn else b""
            else:
                start = _line(head)
            handle.write(start + body)
            handle.flush()
            os.fsync(handle.fileno())

    def _rewrite(self) -> None:
        atomic_write_bytes(self.path, _line(HEADER) + b"".join(self._lines.values()), durable=True)

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
        """Record one episode durably: a single write of whole lines, flushed and fsynced.

        An episode that already has a row (run again: ``retry_failed``, or after it stopped
        the run) has that row replaced, by rewriting the file under a temporary name: the
        file never holds two rows of one episode, which ``score`` would refuse.
        """
        line = _line(result_to_json_dict(result))
        if key_of(result) in self._rows:
            self._replace(result, line)
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new_file = not self.path.exists() or self.path.stat().st_size == 0
        data = _line(HEADER) + line if new_file else line
        start = 0
        try:
            with self.path.open("ab") as handle:
                start = handle.tell()
                write_or_crash("results-row", handle, data)  # test hook, else a plain write
                handle.flush()
                os.fsync(handle.fileno())
        except OSError as error:
            self._take_back(start)
            episode = "/".join(key_of(result))
            raise ResultsWriteError(str(self.path), episode, len(self._rows), error) from error
        if new_file:  # its name in the folder synced too, not only its bytes
            sync_directory(self.path.parent)
        self._rows[key_of(result)] = result
        self._lines[key_of(result)] = line

    def _replace(self, result: EpisodeResult, line: bytes) -> None:
        lines = self._lines | {key_of(result): line}
        try:
            atomic_write_bytes(self.path, _line(HEADER) + b"".join(lines.values()), durable=True)
        except OSError as error:
            episode = "/".join(key_of(result))
            raise ResultsWriteError(str(self.path), episode, len(self._rows), error) from error
        self._rows[key_of(result)] = result
        self._lines = lines

    def _take_back(self, size: int) -> None:
        """Cut a failed append's partial line off (freeing space, so this can succeed)."""
        try:
            with self.path.open("r+b") as handle:
                handle.truncate(size)
        except OSError:  # then the next opening sets the partial line aside
            pass

    def missing(self, keys: Iterable[RowKey], retry_failed: bool = False) -> list[RowKey]:
        """Keys without a row (or, with ``retry_failed``, whose row is an error), in order.

        A row that stopped the run (``extra["fatal"]``: refused credentials, a full disk)
        says nothing about its episode, which is therefore run again.
        """
        out = []
        for key in keys:
            row = self._rows.get(key)
            if row is None or row.stopped_the_run or (retry_failed and row.status == "error"):
                out.append(key)
        return out
