"""Check MCAP logs and converted folders, reporting every problem found.

For a file: every byte verified (magic, footer, summary, data and chunk CRCs, statistics,
see :func:`read_log`), the format and own-schema versions, the episode records
re-parsed, each topic written with its declared schema, and every message decoded as JSON
and validated against the JSON schema stored in its own channel (plus: ``timestamp``
equals the log time, base64 image data decodes); for an episode log (not a run's), every
message but the images equal to what its metadata's records make, and as many images as
its metadata says. For a folder with a manifest: every
listed file present, named after its episode id, with the listed content hash (so it is
the very file the conversion wrote), and no unlisted logs; its ``left_out.json`` (what the
conversion left out, and why) the one whose hash the manifest records, readable and
reported, not a problem (an episode whose conversion failed is one). A run directory's logs
(``RUN_DIR/logs/SPLIT/``, beside the run's ``run.json``) have no manifest: their files are
checked one by one.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from skyvln_eval.avdn import Episode
from skyvln_eval.converters import topics
from skyvln_eval.converters.convert import CLOCK_STEP_NS, convert_episode
from skyvln_eval.converters.left_out import LEFT_OUT_NAME, LeftOut, read_left_out
from skyvln_eval.converters.manifest import (
    MANIFEST_NAME,
    episode_file_name,
    manifest_left_out_sha256,
    read_manifest,
)
from skyvln_eval.converters.reader import (
    LogChannel,
    LogMessage,
    McapLog,
    episode_from_log,
    read_log,
    read_log_bytes,
)
from skyvln_eval.converters.writer import McapLogWriter
from skyvln_eval.errors import SkyvlnError, ValidationIssue
from skyvln_eval.fileio import sha256_file

#: Problems listed per channel before the rest are summarised in one line.
MAX_ISSUES_PER_CHANNEL: Final = 5
#: A run directory's layout (``harness.run.REPORT_FILE``, ``harness.runner.LOGS_DIR``;
#: not imported: the harness imports the converters).
RUN_REPORT_FILE: Final = "run.json"
RUN_LOGS_DIR: Final = "logs"

_validators: dict[bytes, Any] = {}


@dataclass(frozen=True)
class LogCheck:
    """The outcome of checking one file: its message count and every issue."""

    path: str
    messages: int
    issues: tuple[ValidationIssue, ...]


def _validator(channel: LogChannel) -> Any:
    """The validator of a channel's messages: the toolkit's own copy of a schema it knows
    (a file's own copy may be wrong: :func:`_schema_differs`), else the file's schema."""
    known = topics.SCHEMAS.get(channel.schema_name)
    data = topics.schema_bytes(channel.schema_name) if known is not None else channel.schema_data
    validator = _validators.get(data)
    if validator is None:
        import jsonschema  # here: its import takes up to 2 s, which every run would pay

        schema = json.loads(data)
        cls = jsonschema.validators.validator_for(schema, default=jsonschema.Draft202012Validator)
        cls.check_schema(schema)
        validator = cls(schema)
        _validators[data] = validator
    return validator


def _schema_differs(channel: LogChannel) -> str | None:
    """Why a channel's schema is not the toolkit's copy of the schema it names, if it is
    not (e.g. a foxglove.CompressedImage without the base64 ``contentEncoding`` Foxglove
    decodes ``data`` by); None for a schema the toolkit does not know."""
    if channel.schema_name not in topics.SCHEMAS:
        return None
    try:
        found = json.loads(channel.schema_data)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return f"schema {channel.schema_name} is not valid JSON"
    if found == topics.schema_json(channel.schema_name):
        return None
    return (
        f"schema {channel.schema_name} differs from the toolkit's copy (Foxglove and the "
        "reader expect that one); its messages were checked against the toolkit's"
    )


def _message_problems(message: LogMessage, validator: Any) -> list[tuple[str, str]]:
    """(field path, problem) pairs for one message."""
    try:
        value = message.decode()
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        return [("", f"not valid JSON: {exc}")]
    problems = [
        ("/".join(str(p) for p in error.absolute_path), error.message)
        for error in validator.iter_errors(value)
    ]
    if not isinstance(value, dict):
        return problems
    stamp = value.get("timestamp")
    if isinstance(stamp, dict) and all(type(stamp.get(k)) is int for k in ("sec", "nsec")):
        t_ns = stamp["sec"] * 1_000_000_000 + stamp["nsec"]
        if t_ns != message.log_time_ns:
            problems.append(
                ("timestamp", f"is {t_ns} ns but the log time is {message.log_time_ns} ns")
            )
    if message.schema_name == topics.COMPRESSED_IMAGE and isinstance(value.get("data"), str):
        try:
            base64.b64decode(value["data"], validate=True)
        except (binascii.Error, ValueError) as exc:
            problems.append(("data", f"is not valid base64: {exc}"))
    return problems


def _channel_issues(log: McapLog) -> list[ValidationIssue]:
    issues: list[ValidationIssue] = []
    for channel in log.channels:
        declared = topics.TOPICS.get(channel.topic)
        if declared is not None and declared != channel.schema_name:
            issues.append(
                ValidationIssue(
                    log.path,
                    f"written with schema {channel.schema_name}, declared {declared}",
                    field=channel.topic,
                )
            )
        differs = _schema_differs(channel)
        if differs is not None:
            issues.append(ValidationIssue(log.path, differs, field=channel.topic))
        encodings = (channel.schema_encoding, channel.message_encoding)
        if encodings != (topics.SCHEMA_ENCODING, topics.MESSAGE_ENCODING):
            issues.append(
                ValidationIssue(
                    log.path, f"encodings {encodings} are not jsonschema/json", field=channel.topic
                )
            )
    return issues


def _message_issues(log: McapLog) -> list[ValidationIssue]:
    import jsonschema  # see _validator

    issues: list[ValidationIssue] = []
    by_topic = {c.topic: c for c in log.channels}
    listed: dict[str, int] = {}
    for message in log.messages:
        channel = by_topic[message.topic]
        if (channel.schema_encoding, channel.message_encoding) != (
            topics.SCHEMA_ENCODING,
            topics.MESSAGE_ENCODING,
        ):
            continue
        try:
            validator = _validator(channel)
        except (json.JSONDecodeError, jsonschema.SchemaError) as exc:
            issues.append(
                ValidationIssue(
                    log.path,
                    f"channel schema is not a valid JSON schema: {exc}",
                    field=channel.topic,
                )
            )
            listed[channel.topic] = MAX_ISSUES_PER_CHANNEL + 1
            continue
        for where, problem in _message_problems(message, validator):
            count = listed.get(message.topic, 0) + 1
            listed[message.topic] = count
            if count <= MAX_ISSUES_PER_CHANNEL:
                field = f"{message.topic} message {message.sequence}" + (
                    f" /{where}" if where else ""
                )
                issues.append(ValidationIssue(log.path, problem, field=field))
    for topic, count in listed.items():
        if count > MAX_ISSUES_PER_CHANNEL:
            issues.append(
                ValidationIssue(
                    log.path, f"{count - MAX_ISSUES_PER_CHANNEL} more problem(s)", field=topic
                )
            )
    return issues


def check_log(path: str | Path) -> LogCheck:
    """Every problem of one MCAP log (an unreadable file gives a single issue)."""
    try:
        log = read_log(path)
    except SkyvlnError as exc:
        return LogCheck(str(path), 0, (_unreadable(str(path), exc),))
    return check_loaded_log(log)


def _unreadable(name: str, error: SkyvlnError) -> ValidationIssue:
    # The reader's errors start with the file's name, which the issue shows already.
    return ValidationIssue(name, str(error).removeprefix(f"{name}: "))


def check_log_bytes(data: bytes, name: str = "<bytes>") -> LogCheck:
    """:func:`check_log` for a log held in memory."""
    try:
        log = read_log_bytes(data, name)
    except SkyvlnError as exc:
        return LogCheck(name, 0, (_unreadable(name, exc),))
    return check_loaded_log(log)


def check_loaded_log(log: McapLog) -> LogCheck:
    """Channel, version, record and message checks of a log that read without damage."""
    issues = _channel_issues(log)
    episode_id = None
    if topics.EPISODE_METADATA in log.metadata:
        try:
            episode = episode_from_log(log)
        except SkyvlnError as exc:
            issues.append(ValidationIssue(log.path, str(exc)))
        else:
            episode_id = episode.episode_id
            if topics.RUN_METADATA not in log.metadata:  # an episode log, not a run's
                issues.extend(_content_issues(log, episode))
    issues.extend(_message_issues(log))
    if episode_id is not None:
        issues = [
            ValidationIssue(i.file, i.message, i.record_index, episode_id, i.field) for i in issues
        ]
    return LogCheck(log.path, len(log.messages), tuple(issues))


#: Topics drawn from the map image, which checking a log does not have at hand.
_IMAGE_TOPICS: Final = frozenset({topics.TOPIC_MAP_TILE, topics.TOPIC_GT_OBSERVATION})


def _content_issues(log: McapLog, episode: Episode) -> list[ValidationIssue]:
    """An episode log must hold what its records make: every message but the images is
    written again from the metadata's records and compared byte for byte; the images are
    counted (one map tile when it has one, one observation per view when it has them).
    A log whose messages were edited after conversion says one thing in its metadata (what
    replays and scores read) and shows another."""
    meta = log.metadata[topics.EPISODE_METADATA]
    buffer = io.BytesIO()
    with McapLogWriter(buffer) as writer:
        convert_episode(episode, None, writer)
    expected = read_log_bytes(buffer.getvalue()).messages
    found = [m for m in log.messages if m.topic not in _IMAGE_TOPICS]
    issues = []
    for want, got in zip(expected, found, strict=False):  # unequal counts: after the loop
        if (want.topic, want.log_time_ns, want.data) != (got.topic, got.log_time_ns, got.data):
            issues.append(
                ValidationIssue(
                    log.path,
                    f"message {got.sequence} is not what the episode's records make "
                    f"(expected {want.topic} at {want.log_time_ns} ns: changed after "
                    "conversion?)",
                    field=got.topic,
                )
            )
            break  # the rest follows from the first difference
    if not issues and len(expected) != len(found):
        issues.append(
            ValidationIssue(
                log.path,
                f"{len(found)} messages besides images, the episode's records make {len(expected)}",
            )
        )
    views = len(episode.gt_path_corners)
    for topic, wanted in (
        (topics.TOPIC_MAP_TILE, [0] if meta.get("map_tile_max_side_px", "0") != "0" else []),
        (
            topics.TOPIC_GT_OBSERVATION,
            [k * CLOCK_STEP_NS for k in range(views)] if meta.get("observations") == "true" else [],
        ),
    ):
        times = [m.log_time_ns for m in log.messages if m.topic == topic]
        if times != wanted:
            issues.append(
                ValidationIssue(
                    log.path,
                    f"{len(times)} message(s), its metadata says {len(wanted)}"
                    + (" (one per view, a second apart)" if topic != topics.TOPIC_MAP_TILE else ""),
                    field=topic,
                )
            )
    return issues


def is_run_logs_folder(folder: str | Path) -> bool:
    """A run's logs of one split (``RUN_DIR/logs/SPLIT/`` with ``RUN_DIR/run.json``)."""
    folder = Path(folder)
    return folder.parent.name == RUN_LOGS_DIR and (folder.parent.parent / RUN_REPORT_FILE).is_file()


def check_manifest_folder(folder: str | Path) -> list[ValidationIssue]:
    """Completeness of a converted folder against its manifest (files, hashes, ids); none
    for a run's logs, which have no manifest (unless one was put there)."""
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    logs = {p.name for p in folder.glob("*.mcap")}
    if not manifest.is_file():
        if is_run_logs_folder(folder):
            return []
        return [
            ValidationIssue(
                str(folder),
                f"{len(logs)} MCAP file(s) but no {MANIFEST_NAME}: a folder of converted logs "
                "has one (`skyvln-eval convert` writes it), and a run's logs sit in "
                f"RUN_DIR/{RUN_LOGS_DIR}/SPLIT/ beside its {RUN_REPORT_FILE}",
            )
        ]
    try:
        rows = read_manifest(manifest)
        left_out_sha256 = manifest_left_out_sha256(manifest)
    except SkyvlnError as exc:  # its message names the manifest already: not twice
        return [ValidationIssue(str(manifest), str(exc).removeprefix(f"{manifest}: "))]
    issues = _left_out_matches(folder / LEFT_OUT_NAME, left_out_sha256)
    for index, row in enumerate(rows):
        path = folder / row.file_name
        if row.file_name != episode_file_name(row.episode_id):
            message = f"file name {row.file_name} is not {episode_file_name(row.episode_id)}"
            issues.append(
                ValidationIssue(str(manifest), message, index, row.episode_id, "file_name")
            )
        if not path.is_file():
            issues.append(
                ValidationIssue(
                    str(manifest),
                    f"lists {row.file_name}, which is missing",
                    index,
                    row.episode_id,
                    "file_name",
                )
            )
        elif sha256_file(path) != row.sha256:
            issues.append(
                ValidationIssue(
                    str(path),
                    "content differs from the manifest's sha256 (changed after conversion)",
                    index,
                    row.episode_id,
                    "sha256",
                )
            )
    listed = {row.file_name for row in rows}
    for name in sorted(logs - listed):
        issues.append(ValidationIssue(str(folder / name), f"not listed in {MANIFEST_NAME}"))
    return issues


def _left_out_matches(path: Path, recorded_sha256: str) -> list[ValidationIssue]:
    """The list of what was left out must be the one the conversion wrote: without it a
    folder that lacks episodes would pass as complete."""
    if not path.is_file():
        what = "missing: what the conversion left out, and why, is no longer told"
    elif sha256_file(path) != recorded_sha256:
        what = f"differs from the one the conversion wrote (its sha256 is in {MANIFEST_NAME})"
    else:
        return []
    return [ValidationIssue(str(path), what)]


def folder_left_out(folder: str | Path) -> tuple[list[LeftOut], list[ValidationIssue]]:
    """What the conversion of a folder chose to leave out (none without a ``left_out.json``:
    a run's logs, or a folder converted before the file existed), and the issues: an
    unreadable file, and each episode the conversion failed to write (a fault, not a
    choice: the folder is not what was asked for)."""
    path = Path(folder) / LEFT_OUT_NAME
    if not path.is_file():
        return [], []
    try:
        entries = read_left_out(path)
    except SkyvlnError as exc:
        return [], [_unreadable(str(path), exc)]
    chosen = [e for e in entries if e.kind != "failed_episode"]
    failed = [
        ValidationIssue(
            str(path), f"its conversion failed: {'; '.join(e.reasons)}", episode_id=e.episode_id
        )
        for e in entries
        if e.kind == "failed_episode"
    ]
    return chosen, failed


def mcap_targets(path: Path) -> tuple[list[Path], list[Path]]:
    """(folders holding a manifest or logs, loose log files) at or below ``path``."""
    if not path.is_dir():
        return [], [path]  # a file, or a missing path that check_log reports as not found
    folders = sorted(
        {p.parent for p in path.rglob("*.mcap")} | {p.parent for p in path.rglob(MANIFEST_NAME)}
    )
    return folders, []


def check_paths(paths: Iterable[Path]) -> tuple[list[LogCheck], list[ValidationIssue]]:
    """Check files and folders of logs: per-file checks and per-folder manifest issues."""
    checks: list[LogCheck] = []
    folder_issues: list[ValidationIssue] = []
    for path in paths:
        folders, files = mcap_targets(path)
        for folder in folders:
            folder_issues.extend(check_manifest_folder(folder))
            folder_issues.extend(folder_left_out(folder)[1])
            files.extend(sorted(folder.glob("*.mcap")))
        checks.extend(check_log(f) for f in files)
    return checks, folder_issues
