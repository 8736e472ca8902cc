"""Per-episode scores files: CSV with the format version and the conventions in its header.

The first two lines are comments::

    # skyvln-eval.scores v3
    # conventions: {"distance":"2d",...}

then a ``# warning: ...`` line per warning its scoring gave (e.g. the scores of an
incomplete run: every table made from the file repeats it), then a CSV header and one row
per episode (the frame of :func:`~skyvln_eval.metrics.scoring.score_results`), sorted by
system, split, mode and episode id so that the file does not depend on the order results
were recorded in. Floats are written with Python's shortest round-trip repr, so reading
gives back the same values; empty cells are "not applicable" (e.g. control metrics of an
episode without dynamics) or, in the ``oracle`` column, "not said".

Version 3 added the warning lines. Version 2 added the ``oracle`` column (the harness's
oracle flew the episode: a table never ranks it). Version 1 files still read, their
``oracle`` cells empty: not said, which is what they say; their rows are ranked as they
always were. The ``llm_backend`` column (what answered the agent's LLM calls: a stand-in
such as ``rule`` is a reference in Table II, never ranked), ``execution_mode`` (official or
dynamics; ``mode`` is the AVDN episode mode) and ``error`` (the first line of an error
episode's error) are optional: a file without them reads with the cells empty.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from skyvln_eval.avdn.constants import SPLITS
from skyvln_eval.errors import (
    ConfigError,
    DataError,
    FormatVersionError,
    ResultRecordError,
    ValidationIssue,
)
from skyvln_eval.fileio import atomic_write_text
from skyvln_eval.metrics.conventions import CONVENTIONS_ATTR, MetricConventions, check_conventions
from skyvln_eval.metrics.records import KEY_COLUMNS
from skyvln_eval.metrics.scoring import CONTROL_COLUMNS, METRIC_UNITS, TEXT_COLUMNS

#: Metric columns added since the scores format's version: a file scored before has none,
#: read as unknown (empty) values rather than refused.
ADDED_METRICS = ("segments_cut_short",)

SCORES_FORMAT = "skyvln-eval.scores"
SCORES_VERSION = 3
#: Versions :func:`read_scores` reads (see the module docstring).
_READABLE_VERSIONS = ("1", "2", "3")
#: Where a scores frame read from a file keeps the file's warnings (``frame.attrs``).
WARNINGS_ATTR = "skyvln_warnings"
_WARNING = "# warning: "
#: Lines before a file's first row: the format, the conventions, the warnings, the CSV
#: header (``frame.attrs``, for naming a row by its line).
_LINES_ATTR = "skyvln_lines_before_rows"


def scores_to_csv_text(
    scores: pd.DataFrame, conventions: MetricConventions, warnings: Sequence[str] = ()
) -> str:
    buffer = io.StringIO()
    buffer.write(f"# {SCORES_FORMAT} v{SCORES_VERSION}\n# conventions: {conventions.to_json()}\n")
    buffer.write("".join(f"{_WARNING}{' '.join(w.split())}\n" for w in warnings))
    ordered = scores.sort_values(list(KEY_COLUMNS), kind="stable")
    ordered.to_csv(buffer, index=False, lineterminator="\n")
    return buffer.getvalue()


def write_scores(
    path: str | Path,
    scores: pd.DataFrame,
    conventions: MetricConventions,
    warnings: Sequence[str] = (),
) -> None:
    """Write a scores CSV atomically (see the module docstring)."""
    atomic_write_text(path, scores_to_csv_text(scores, conventions, warnings))


def summary_csv_text(
    summary: pd.DataFrame, conventions: MetricConventions, warnings: Sequence[str] = ()
) -> str:
    """A summary (from :func:`~skyvln_eval.metrics.summarise`) as CSV with its conventions
    and a ``# warning:`` line per warning (e.g. an incomplete run's scores); unknown means
    (a cost without a price) are written "n/a", which pandas reads as NaN."""
    check_conventions(summary, conventions, "the summary CSV")
    head = f"# conventions: {conventions.to_json()}\n"
    head += "".join(f"# warning: {' '.join(w.split())}\n" for w in warnings)
    return head + summary.to_csv(index=False, lineterminator="\n", na_rep="n/a")


def read_scores(path: str | Path) -> tuple[pd.DataFrame, MetricConventions]:
    """Read a scores CSV; checks the format version and parses the conventions."""
    path = Path(path)
    what = "`skyvln-eval score` writes one as OUT/scores.csv (--out, default scores/)"
    if path.is_dir():
        inside = path / "scores.csv"
        if inside.is_file():
            raise DataError(f"{path}: a folder; its scores are {inside}")
        raise DataError(
            f"{path}: a folder, not a scores file (a run directory? score it first: "
            f"skyvln-eval score {path}); {what}"
        )
    if not path.is_file():
        raise DataError(f"{path}: scores file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a scores file (not UTF-8 text); {what}") from None
    lines = text.split("\n", 2)
    if len(lines) < 3 or not lines[0].startswith(f"# {SCORES_FORMAT} v"):
        raise DataError(
            f"{path}: not a scores file (its first line must be '# {SCORES_FORMAT} "
            f"v{SCORES_VERSION}'); {what}"
        )
    version = lines[0].rsplit("v", 1)[1]
    if version not in _READABLE_VERSIONS:
        raise FormatVersionError(
            str(path), version, SCORES_VERSION, "Rescore the results with `skyvln-eval score`."
        )
    if not lines[1].startswith("# conventions: "):
        raise DataError(f"{path}: line 2 must be '# conventions: {{...}}'")
    try:
        conventions = MetricConventions.from_dict(
            json.loads(lines[1][len("# conventions: ") :]), f"{path} conventions"
        )
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: conventions line is not JSON ({exc.msg})") from None
    except ConfigError as exc:  # e.g. scored by older formulas: say which file
        raise DataError(f"{path}: {exc}") from None
    table, warnings = lines[2], []
    while table.startswith(_WARNING):
        warning, _, table = table.partition("\n")
        warnings.append(warning[len(_WARNING) :])
    try:
        frame = pd.read_csv(
            io.StringIO(table),
            dtype={
                "episode_id": str,
                "split": str,
                "mode": str,
                "system": str,
                "oracle": str,
                **dict.fromkeys(TEXT_COLUMNS, "string"),
            },
            # Only an empty cell is missing, as written: an error line "None" stays text.
            keep_default_na=False,
            na_values=[""],
        )
    except ValueError as exc:  # pandas' ParserError and EmptyDataError among them
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise DataError(f"{path}: the scores table is not valid CSV ({reason})") from None
    lines_before_rows = 3 + len(warnings)
    _check_row_lengths(table, path, lines_before_rows)
    # Its old name: it always counted requests (attempts), not calls.
    frame = frame.rename(columns={"llm_unpriced_calls": "llm_unpriced_requests"})
    said = ("oracle",) if version != "1" else ()
    for column in ADDED_METRICS:
        if column not in frame.columns:  # scored before the scores had it: not known
            frame[column] = pd.array([None] * len(frame), dtype="Float64")
    missing = [c for c in (*KEY_COLUMNS, "status", *said, *METRIC_UNITS) if c not in frame.columns]
    if missing:
        shown = ", ".join(missing[:8]) + (
            f" ... ({len(missing)} in all)" if len(missing) > 8 else ""
        )
        raise DataError(
            f"{path}: the scores table lacks column(s) {shown}; score the results again "
            "with `skyvln-eval score`"
        )
    for column in CONTROL_COLUMNS:
        if column in frame.columns:
            frame[column] = frame[column].astype("Float64")
    frame.attrs[_LINES_ATTR] = lines_before_rows
    _check_numbers(frame, path)
    _check_splits(frame, path)
    _read_oracle(frame, path)
    after = "oracle"
    for column in TEXT_COLUMNS:
        if column not in frame.columns:  # scored before the scores said (not known)
            empty = pd.array([None] * len(frame), dtype="string")
            frame.insert(frame.columns.get_loc(after) + 1, column, empty)
        after = column
    check_unique_scores([(str(path), frame)])
    frame.attrs[CONVENTIONS_ATTR] = conventions
    frame.attrs[WARNINGS_ATTR] = warnings
    return frame, conventions


def _check_row_lengths(table: str, path: Path, lines_before_rows: int) -> None:
    """Refuse a row with fewer cells than the header (a file cut short, or a row edited by
    hand): pandas would fill the cells it lacks as empty, which reads "not applicable", so
    a cut-off row would lose its status and its metrics without a word."""
    rows = csv.reader(io.StringIO(table))
    header = next(rows, [])
    for cells in rows:
        if cells and len(cells) != len(header):
            # The reader's line count is where the row ends (a quoted cell may hold lines).
            raise DataError(
                f"{path}: line {rows.line_num + lines_before_rows - 1} has {len(cells)} of the "
                f"header's {len(header)} cells (a file cut short, or edited by hand?); score "
                "the results again with `skyvln-eval score`"
            )


def _check_numbers(frame: pd.DataFrame, path: Path) -> None:
    """Every metric cell a number or empty: a table would stop at the first text with a
    bare ValueError; this names the file, line, episode and column."""
    for column in METRIC_UNITS:
        if column not in frame.columns or pd.api.types.is_numeric_dtype(frame[column]):
            continue
        numbers = pd.to_numeric(frame[column], errors="coerce")
        _refuse_first(
            frame, path, column, frame[column].notna() & numbers.isna(), "is not a number"
        )


def _check_splits(frame: pd.DataFrame, path: Path) -> None:
    """Every row of an AVDN split: a table has a column per split and would leave a row of
    another out without a word."""
    _refuse_first(frame, path, "split", ~frame["split"].isin(SPLITS), f"is not one of {SPLITS}")


def _refuse_first(frame: pd.DataFrame, path: Path, column: str, bad: pd.Series, what: str) -> None:
    """Raise for the first ``bad`` row, naming its line, episode and ``column``."""
    if not bad.any():
        return
    row = int(np.flatnonzero(bad.to_numpy())[0])
    where = (row, str(frame["episode_id"].iloc[row]), column, _line(row, frame))
    issue = ValidationIssue(str(path), f"{frame[column].iloc[row]!r} {what}", *where)
    raise ResultRecordError(issue)


def scores_warnings(frame: pd.DataFrame) -> list[str]:
    """The warnings of the scores files ``frame`` was read from (:func:`read_scores`)."""
    return list(frame.attrs.get(WARNINGS_ATTR, []))


def _read_oracle(frame: pd.DataFrame, path: Path) -> None:
    """The ``oracle`` column as nullable booleans, after ``status``; all empty (not said)
    in a version 1 file, which has none."""
    if "oracle" not in frame.columns:
        empty = pd.array([None] * len(frame), dtype="boolean")
        frame.insert(frame.columns.get_loc("status") + 1, "oracle", empty)
        return
    text = frame["oracle"]  # read as text, so that a cell neither True nor False is named
    values = text.map({"True": True, "False": False}).astype("boolean")
    bad = text.notna() & values.isna()
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        where = _row_name(str(path), row, frame)
        raise DataError(f"{where}: oracle is {text.iloc[row]!r}, not True, False or empty")
    frame["oracle"] = values


def _row_name(file: str, row: int, frame: pd.DataFrame) -> str:
    return f"record {row} of {file} (line {_line(row, frame)})"


def _line(row: int, frame: pd.DataFrame) -> int:
    """The line of the file ``frame`` was read from that holds its ``row``."""
    return row + 1 + int(frame.attrs.get(_LINES_ATTR, 3))


def check_unique_scores(files: Sequence[tuple[str, pd.DataFrame]]) -> None:
    """Raise if two rows of ``files`` (name, scores frame) share ``(system, split, mode,
    episode_id)``, naming both files and rows: concatenated, they would be averaged as
    one system (an episode counted twice, or two runs that share a label merged)."""
    seen: dict[tuple[str, ...], tuple[int, int]] = {}  # key -> (file index, row)
    for index, (file, frame) in enumerate(files):
        keys = frame[list(KEY_COLUMNS)].astype(str).itertuples(index=False, name=None)
        for row, key in enumerate(keys):
            first = seen.setdefault(key, (index, row))
            if first == (index, row):
                continue
            system, split, mode, episode_id = key
            first_file = "this file" if first[0] == index else files[first[0]][0]
            earlier = _row_name(first_file, first[1], files[first[0]][1])
            message = (
                f"line {_line(row, frame)} duplicates {earlier}: same system {system!r}, split "
                f"{split} and mode {mode}, which a table would average as one. Different runs "
                "need different system labels (the `system` of their run configs, or "
                "`score --system` for predictions); the same scores must be given once."
            )
            issue = ValidationIssue(file, message, row, episode_id, "episode_id")
            raise ResultRecordError(issue)


def read_many_scores(paths: Sequence[str | Path]) -> tuple[pd.DataFrame, MetricConventions]:
    """Concatenate scores files made under the same conventions (else raise, naming both)
    that share no episode of a system, split and mode (else raise, naming both rows)."""
    if not paths:
        raise DataError("no scores files given")
    frames = []
    first: MetricConventions | None = None
    for path in paths:
        frame, conventions = read_scores(path)
        if first is not None and conventions != first:
            raise DataError(
                f"{path}: scored under different conventions ({conventions.describe()}) than "
                f"{paths[0]} ({first.describe()}); rescore one of them"
            )
        first = conventions
        frames.append((str(path), frame))
    assert first is not None  # paths is non-empty
    check_unique_scores(frames)
    joined = pd.concat([frame for _, frame in frames], ignore_index=True)
    joined.attrs[CONVENTIONS_ATTR] = first
    joined.attrs[WARNINGS_ATTR] = [w for _, frame in frames for w in scores_warnings(frame)]
    return joined, first
