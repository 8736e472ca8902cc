"""Lossless, versioned files of :class:`EpisodeResult` rows: JSON lines and parquet.

JSON lines (``.jsonl``): the first line is the header
``{"format": "skyvln-eval.episode-results", "version": 1}``; every further line is one
result::

    {"episode_id": "1913__3_1", "split": "val_unseen", "mode": "andh",
     "system": "SkyVLN full", "status": "ok", "error": null,
     "visited_views": [[[lat, lng] x 4], ...], "gt_path_corners": [[[lat, lng] x 4], ...],
     "control": null | {ControlSummary fields}, "control_log": null | "logs/x.parquet",
     "llm_calls": [{LlmCall fields}, ...], "decisions": 9,
     "module_failures": [{ModuleFailure fields}, ...],
     "llm_modules": {module: {calls, failed_calls, ...}}, "extra": {}}

``llm_modules`` is derived from ``llm_calls`` and ``module_failures`` and written for
readers of the file only.

Floats are written with Python's shortest round-trip repr, so reading gives back the
same bits. Parquet (``.parquet``) holds the same rows, views as nested float64 lists and
``control`` / ``llm_calls`` / ``module_failures`` / ``extra`` as JSON text; the format and
version are in the file's schema metadata. Both readers check the version and name the
file, row and field of any problem. Writers write to a temporary name and rename.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from skyvln_eval.errors import (
    DataError,
    FormatVersionError,
    IncompleteRunError,
    ResultRecordError,
    ValidationIssue,
)
from skyvln_eval.fileio import atomic_write_bytes, object_with_unique_keys, undecodable_at
from skyvln_eval.llm_records import LlmCall, ModuleFailure
from skyvln_eval.metrics.records import ControlSummary, EpisodeResult

T = TypeVar("T")
RESULTS_FORMAT = "skyvln-eval.episode-results"
RESULTS_VERSION = 2
_FIELDS = (
    "episode_id",
    "split",
    "mode",
    "system",
    "status",
    "error",
    "visited_views",
    "gt_path_corners",
    "control",
    "control_log",
    "llm_calls",
    "decisions",
    "module_failures",
    "extra",
)
#: Written for readers of the file (jq, pandas), derived from the rows' own records and
#: not read back: per agent module, calls, failures, repairs, fallbacks, tokens, LLM time.
_DERIVED = ("llm_modules",)
_UPGRADE_HINT = "Rewrite the results with this toolkit version (rerun or convert the run)."


def result_to_json_dict(result: EpisodeResult) -> dict[str, Any]:
    """One result as plain JSON data (the shape of a JSON-lines row)."""
    return {
        "episode_id": result.episode_id,
        "split": result.split,
        "mode": result.mode,
        "system": result.system,
        "status": result.status,
        "error": result.error,
        "visited_views": result.visited_views.tolist(),
        "gt_path_corners": result.gt_path_corners.tolist(),
        "control": None if result.control is None else result.control.to_json_dict(),
        "control_log": result.control_log,
        "llm_calls": [c.to_json_dict() for c in result.llm_calls],
        "decisions": result.decisions,
        "module_failures": [f.to_json_dict() for f in result.module_failures],
        "llm_modules": result.llm_modules(),
        "extra": dict(result.extra),
    }


def _where(
    file: str,
    row: int,
    episode_id: str | None,
    field: str,
    message: str,
    line: int | None = None,
) -> ResultRecordError:
    return ResultRecordError(ValidationIssue(file, message, row, episode_id, field, line))


def _records(items: Any, name: str, parse: Callable[[Any], T]) -> tuple[T, ...]:
    """Each item parsed; a bad one's error names ``name[index].field``."""
    if not isinstance(items, list):
        raise ResultRecordError(ValidationIssue("<json>", "must be a list", field=name))
    out = []
    for index, item in enumerate(items):
        try:
            out.append(parse(item))
        except ResultRecordError as error:
            where = f"{name}[{index}]" + (f".{error.issue.field}" if error.issue.field else "")
            issue = ValidationIssue("<json>", error.issue.message, field=where)
            raise ResultRecordError(issue) from None
        except TypeError as error:  # a missing or misspelt key
            raise ResultRecordError(
                ValidationIssue("<json>", str(error), field=f"{name}[{index}]")
            ) from None
    return tuple(out)


def result_from_json_dict(
    data: Any, file: str = "<json>", row: int = 0, line: int | None = None
) -> EpisodeResult:
    """Parse one row; errors name ``file``, ``row`` (and its ``line`` in a JSON Lines
    file), the episode and the field."""

    def error(field: str, message: str) -> ResultRecordError:
        return _where(file, row, eid, field, message, line)

    eid = None
    if not isinstance(data, dict):
        raise error("", f"expected a JSON object, got {type(data).__name__}")
    eid = data.get("episode_id") if isinstance(data.get("episode_id"), str) else None
    missing = [k for k in _FIELDS if k not in data]
    if missing:
        raise error(missing[0], f"missing required key(s) {missing}")
    unknown = sorted(set(data) - set(_FIELDS) - set(_DERIVED))
    if unknown:
        raise error(unknown[0], f"unknown key(s) {unknown}")
    try:
        control = _control_summary(data["control"])
        calls = _records(data["llm_calls"], "llm_calls", LlmCall.from_json_dict)
        failures = _records(
            data["module_failures"], "module_failures", ModuleFailure.from_json_dict
        )
        if not isinstance(data["extra"], dict):
            raise error("extra", "must be a JSON object")
        _check_extra(data["extra"])
        result = EpisodeResult(
            episode_id=data["episode_id"],
            split=data["split"],
            mode=data["mode"],
            system=data["system"],
            status=data["status"],
            error=data["error"],
            visited_views=data["visited_views"] or np.zeros((0, 4, 2)),
            gt_path_corners=data["gt_path_corners"],
            control=control,
            control_log=data["control_log"],
            llm_calls=calls,
            decisions=data["decisions"],
            module_failures=failures,
            extra=data["extra"],
        )
        _check_starts_at_start(result)
        if result.status != "error" and result.error:  # which one says what happened?
            raise error(
                "error",
                f"the episode is {result.status!r}, which has no error; got {result.error!r}",
            )
        return result
    except ResultRecordError as exc:
        raise error(exc.issue.field or "", exc.issue.message) from None
    except (TypeError, ValueError) as exc:  # not one of the checks above: no field to name
        raise error("", str(exc)) from None


#: How far (degrees, about a centimetre) a path's first view (a results row's, a
#: prediction's) may be from the episode's start view.
START_VIEW_TOLERANCE_DEG = 1e-7


def _check_starts_at_start(result: EpisodeResult) -> None:
    """A row's path begins at its start view (a row whose first view was cut off, by hand,
    scored a shorter path and a higher SPL without a word)."""
    visited, start = result.visited_views, result.gt_path_corners[0]
    if len(visited) and not np.allclose(visited[0], start, rtol=0.0, atol=START_VIEW_TOLERANCE_DEG):
        raise ResultRecordError(
            ValidationIssue(
                "<json>",
                f"must be the episode's start view (gt_path_corners[0], {start.tolist()}), got "
                f"{visited[0].tolist()}: a path lists every view from the start on",
                field="visited_views[0]",
            )
        )


def _check_extra(extra: dict[str, Any]) -> None:
    """The facts of ``extra`` that scores are made of have their types (a hand edit's
    ``"wall_s": "slow"`` was a traceback in ``score``, after ``validate`` said ok)."""

    def problem(key: str, message: str) -> ResultRecordError:
        return ResultRecordError(ValidationIssue("<json>", message, field=f"extra.{key}"))

    wall = extra.get("wall_s")
    if wall is not None and (
        isinstance(wall, bool)
        or not isinstance(wall, int | float)
        or not math.isfinite(wall)
        or wall < 0
    ):
        raise problem("wall_s", f"must be a number of seconds >= 0, got {wall!r}")
    for key in ("oracle", "llm_use_recorded"):
        if extra.get(key) is not None and not isinstance(extra[key], bool):
            raise problem(key, f"must be true or false, got {extra[key]!r}")
    for key in ("llm_backend", "detector", "settings_digest", "system_digest", "execution_mode"):
        if extra.get(key) is not None and not isinstance(extra[key], str):
            raise problem(key, f"must be a string, got {extra[key]!r}")
    rounds = extra.get("rounds_flown")
    if rounds is not None and (
        isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1
    ):
        raise problem("rounds_flown", f"must be a whole number >= 1, got {rounds!r}")
    questions = extra.get("questions")
    if questions is not None and (
        not isinstance(questions, list) or not all(isinstance(q, dict) for q in questions)
    ):
        raise problem("questions", f"must be a list of question objects, got {questions!r}")


def _control_summary(data: Any) -> ControlSummary | None:
    def problem(message: str) -> ResultRecordError:
        return ResultRecordError(ValidationIssue("<json>", message, field="control"))

    if data is None:
        return None
    if not isinstance(data, dict):
        raise problem("must be a JSON object or null")
    keys = {f.name: f.default is dataclasses.MISSING for f in dataclasses.fields(ControlSummary)}
    missing = [name for name, required in keys.items() if required and name not in data]
    if missing:
        raise problem(f"missing required key(s) {missing}")
    unknown = sorted(set(data) - set(keys))
    if unknown:
        raise problem(f"unknown key(s) {unknown}")
    return ControlSummary(**data)


def check_unique(results: Sequence[EpisodeResult], file: str = "<results>") -> None:
    """Raise if two rows share ``(system, split, mode, episode_id)``."""
    check_unique_files([(file, results)])


def check_unique_files(files: Sequence[tuple[str, Sequence[EpisodeResult]]]) -> None:
    """Raise if two rows of ``files`` (name, rows) share ``(system, split, mode,
    episode_id)``, naming the file and row of both: scored together, an episode would
    count twice, or two runs that share a system label would be averaged as one."""
    seen: dict[tuple[str, str, str, str], tuple[int, int]] = {}  # key -> (file index, row)
    for index, (file, results) in enumerate(files):
        for row, result in enumerate(results):
            first = seen.setdefault(result.key, (index, row))
            if first == (index, row):
                continue
            where = "this file" if first[0] == index else files[first[0]][0]
            message = f"duplicate of record {first[1]} of {where} (same system, split and mode)"
            if first[0] != index:
                message += (
                    f"; scored together they would be averaged as one system "
                    f"({result.system!r}): different runs need different system labels (the "
                    "`system` of their run configs, or `score --system` for predictions), "
                    "and a file must be given once"
                )
            raise _where(file, row, result.episode_id, "episode_id", message)


def check_one_configuration_per_system(results: Sequence[EpisodeResult]) -> None:
    """Raise if one system's rows were made by different run configurations (their
    ``extra["system_digest"]``: the settings that decide a result, whatever the splits,
    data and selection): a table would pool them in one row, e.g. an official-mode run on
    one split and a flown one on another under the same label. Rows that do not record it
    (older runs, predictions) are not checked."""
    seen: dict[str, tuple[str, EpisodeResult]] = {}  # system -> (digest, first row)
    for result in results:
        digest = result.extra.get("system_digest")
        if not isinstance(digest, str):
            continue
        first_digest, first = seen.setdefault(result.system, (digest, result))
        if first_digest != digest:
            raise ResultRecordError(
                ValidationIssue(
                    "<results>",
                    f"system {result.system!r} has rows made by different run configurations "
                    f"({first.split}/{first.episode_id}: {first_digest}, "
                    f"{result.split}/{result.episode_id}: {digest}; each run's config.yaml "
                    "says what it ran), which a table would pool in one row; give the runs "
                    "different system labels",
                    episode_id=result.episode_id,
                    field="system",
                )
            )


def results_to_jsonl_bytes(results: Iterable[EpisodeResult]) -> bytes:
    header = json.dumps({"format": RESULTS_FORMAT, "version": RESULTS_VERSION})
    lines = [header]
    lines += [
        json.dumps(result_to_json_dict(r), allow_nan=False, ensure_ascii=False) for r in results
    ]
    return ("\n".join(lines) + "\n").encode("utf-8")


def _check_header(header: Any, file: str) -> None:
    if not isinstance(header, dict) or header.get("format") != RESULTS_FORMAT:
        raise DataError(
            f"{file}: not an episode-results file (its first line must be "
            f'{{"format": "{RESULTS_FORMAT}", "version": {RESULTS_VERSION}}})'
        )
    if header.get("version") != RESULTS_VERSION:
        raise FormatVersionError(file, header.get("version"), RESULTS_VERSION, _UPGRADE_HINT)


def _given_twice(key: str) -> ValueError:
    return ValueError(f"the key {key!r} is given twice")


#: ``json.loads``' object hook for a results row: each key once.
_ROW_OBJECT = functools.partial(object_with_unique_keys, refuse=_given_twice)


def results_from_jsonl_bytes(data: bytes, file: str = "<jsonl>") -> list[EpisodeResult]:
    try:
        lines = data.decode("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        where = undecodable_at(data, exc)
        raise DataError(f"{file}: not an episode-results file (not UTF-8 text: {where})") from None
    if not lines:
        raise DataError(f"{file}: empty file (no header line)")
    try:
        _check_header(json.loads(lines[0]), file)
    except json.JSONDecodeError as exc:
        raise DataError(f"{file}: header line is not JSON ({exc.msg})") from None
    except ValueError as exc:  # an integer of thousands of digits
        raise DataError(f"{file}: header line is not usable JSON ({exc})") from None
    results = []
    for row, line in enumerate(lines[1:]):
        if not line.strip():
            continue
        try:
            obj = json.loads(line, object_pairs_hook=_ROW_OBJECT)
        except json.JSONDecodeError as exc:
            message = f"not valid JSON (column {exc.colno}: {exc.msg})"
            if row + 2 == len(lines) and not data.endswith(b"\n"):
                # The last row, without its line end: a write cut short (a killed run).
                message += (
                    "; it is the last row and has no line end: a write cut short, as a "
                    "killed run leaves; resume the run (the same command) to set it aside "
                    "and run its episode again"
                )
            raise _where(file, row, None, "", message, line=row + 2) from None
        except ValueError as exc:  # a key given twice, an integer of thousands of digits
            raise _where(file, row, None, "", f"not usable JSON: {exc}", line=row + 2) from None
        results.append(result_from_json_dict(obj, file, row, line=row + 2))
    check_unique(results, file)
    return results


def _parquet_table(results: Sequence[EpisodeResult]) -> Any:
    import pyarrow as pa

    views = pa.list_(pa.list_(pa.list_(pa.float64(), 2), 4))
    columns = {
        "episode_id": pa.array([r.episode_id for r in results], pa.string()),
        "split": pa.array([r.split for r in results], pa.string()),
        "mode": pa.array([r.mode for r in results], pa.string()),
        "system": pa.array([r.system for r in results], pa.string()),
        "status": pa.array([r.status for r in results], pa.string()),
        "error": pa.array([r.error for r in results], pa.string()),
        "visited_views": pa.array([r.visited_views.tolist() for r in results], views),
        "gt_path_corners": pa.array([r.gt_path_corners.tolist() for r in results], views),
        "control": pa.array(
            [None if r.control is None else json.dumps(r.control.to_json_dict()) for r in results],
            pa.string(),
        ),
        "control_log": pa.array([r.control_log for r in results], pa.string()),
        "llm_calls": pa.array(
            [json.dumps([c.to_json_dict() for c in r.llm_calls]) for r in results], pa.string()
        ),
        "decisions": pa.array([r.decisions for r in results], pa.int64()),
        "module_failures": pa.array(
            [json.dumps([f.to_json_dict() for f in r.module_failures]) for r in results],
            pa.string(),
        ),
        "extra": pa.array(
            [json.dumps(dict(r.extra), sort_keys=True) for r in results], pa.string()
        ),
    }
    meta = {
        b"skyvln_eval.format": RESULTS_FORMAT.encode(),
        b"skyvln_eval.version": str(RESULTS_VERSION).encode(),
    }
    return pa.table(columns).replace_schema_metadata(meta)


def results_to_parquet_bytes(results: Sequence[EpisodeResult]) -> bytes:
    import pyarrow.parquet as pq

    sink = io.BytesIO()
    pq.write_table(_parquet_table(results), sink, compression="zstd")
    return sink.getvalue()


def results_from_parquet_bytes(data: bytes, file: str = "<parquet>") -> list[EpisodeResult]:
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(io.BytesIO(data))
    except Exception as exc:  # pyarrow raises several unrelated types for a bad file
        raise DataError(f"{file}: not a readable parquet file ({exc})") from None
    meta = table.schema.metadata or {}
    if meta.get(b"skyvln_eval.format") != RESULTS_FORMAT.encode():
        raise DataError(
            f"{file}: not an episode-results parquet file (no '{RESULTS_FORMAT}' metadata)"
        )
    version = meta.get(b"skyvln_eval.version", b"?").decode()
    if version != str(RESULTS_VERSION):
        raise FormatVersionError(file, version, RESULTS_VERSION, _UPGRADE_HINT)
    results = []
    for row, rec in enumerate(table.to_pylist()):
        for key in ("control", "llm_calls", "module_failures", "extra"):
            rec[key] = None if rec[key] is None else json.loads(rec[key])
        results.append(result_from_json_dict(rec, file, row))
    check_unique(results, file)
    return results


def write_results(path: str | Path, results: Sequence[EpisodeResult]) -> None:
    """Write results atomically; the suffix (``.jsonl`` or ``.parquet``) picks the format."""
    path = Path(path)
    check_unique(results, str(path))
    if path.suffix == ".jsonl":
        atomic_write_bytes(path, results_to_jsonl_bytes(results))
    elif path.suffix == ".parquet":
        atomic_write_bytes(path, results_to_parquet_bytes(results))
    else:
        raise DataError(f"{path}: unknown results format; use a .jsonl or .parquet name")


def read_results(path: str | Path, *, allow_incomplete: bool = False) -> list[EpisodeResult]:
    """Read a results file written by :func:`write_results` (format by suffix).

    A run's ``results.jsonl`` may hold a row that only records the run stopping there
    (refused credentials, a full disk: ``extra["fatal"]``): it is no episode's result, and
    the run's later episodes never ran. Such a file raises
    :class:`~skyvln_eval.errors.IncompleteRunError`; ``allow_incomplete`` reads the rows
    of the episodes that ran, leaving those out. This reads one file: which episodes a
    run was to cover is its directory's (:func:`skyvln_eval.harness.run_results` checks
    them all, as ``skyvln-eval score`` does).
    """
    rows = read_result_rows(path)
    stopped = [r for r in rows if r.stopped_the_run]
    if stopped and not allow_incomplete:
        raise stopped_run_error(str(path), stopped)
    return [r for r in rows if not r.stopped_the_run]


def read_result_rows(path: str | Path) -> list[EpisodeResult]:
    """Every row of a results file as written, a row that only records a run stopping
    included (for readers that account for them, e.g. ``score``'s coverage check)."""
    path = Path(path)
    if path.is_dir():
        raise DataError(
            f"{path}: a directory, not a results file; pass the file in it "
            f"({path / 'results.jsonl'}), or read a run directory with "
            "skyvln_eval.harness.run_results, which checks that the run covers its episodes"
        )
    if not path.is_file():
        raise DataError(f"{path}: results file not found")
    if path.suffix == ".jsonl":
        return results_from_jsonl_bytes(path.read_bytes(), str(path))
    if path.suffix == ".parquet":
        return results_from_parquet_bytes(path.read_bytes(), str(path))
    raise DataError(f"{path}: unknown results format; expected .jsonl or .parquet")


def stopped_run_error(file: str, stopped: Sequence[EpisodeResult]) -> IncompleteRunError:
    """The error for results of ``file`` whose ``stopped`` rows only record the run
    stopping there (``extra["fatal"]``)."""
    reason = (str(stopped[0].extra["fatal"]).strip().splitlines() or ["no reason"])[0][:200]
    return IncompleteRunError(
        f"results file {file}",
        [f"{r.split}/{r.episode_id}" for r in stopped],
        hint=(
            f"{len(stopped)} row(s) only record that the run stopped there ({reason}), not "
            "an episode's result, and the episodes after them never ran. Finish the run (the "
            "same `skyvln-eval run` command resumes it); read its directory with "
            "skyvln_eval.harness.run_results to have every missing episode named; or pass "
            "allow_incomplete=True to read the rows of the episodes that ran"
        ),
    )
