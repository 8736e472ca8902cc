"""Load AVDN splits from disk: ``annotations/<split>_data.json`` and ``train_images/``.

``load_split`` validates every record (see :mod:`skyvln_eval.avdn.validation`), checks
that each map image exists, and either raises with every problem or, with
``skip_invalid=True``, loads the rest and reports what it skipped in ``AvdnSplit.skipped``.
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from skyvln_eval.avdn.constants import (
    ANNOTATIONS_DIR,
    IMAGES_DIR,
    SPLITS,
    EpisodeMode,
    annotation_file_name,
)
from skyvln_eval.avdn.imagery import map_image_path
from skyvln_eval.avdn.json_values import read_json_float
from skyvln_eval.avdn.records import AvdnRecord, Episode
from skyvln_eval.avdn.validation import parse_records_indexed, record_place
from skyvln_eval.errors import (
    AvdnFileError,
    AvdnValidationError,
    ConfigError,
    NoGroundTruthError,
    ValidationIssue,
)
from skyvln_eval.fileio import undecodable_at

TrajectoryKey = tuple[str, str]


@dataclass(frozen=True)
class SkippedRecord:
    """A record left out as invalid: its place in the file, the map, trajectory and round it
    names (None where unreadable), and every issue found in it."""

    record_index: int
    map_name: str | None
    trajectory_index: str | None
    round_index: int | None
    issues: tuple[ValidationIssue, ...]

    @property
    def episode_id(self) -> str | None:
        return next((i.episode_id for i in self.issues if i.episode_id is not None), None)

    @property
    def reasons(self) -> tuple[str, ...]:
        """Each issue without the file and record (for a line that names them)."""
        return tuple(
            f"field '{i.field}': {i.message}" if i.field else i.message for i in self.issues
        )

    @property
    def reason(self) -> str:
        return self.reasons[0]

    def __str__(self) -> str:
        """One line: the file, record and episode, then every problem of the record."""
        first = self.issues[0]
        where = ValidationIssue(first.file, "", self.record_index, self.episode_id)
        return f"{where.record_location}: {'; '.join(self.reasons)}"


@dataclass(frozen=True)
class AvdnSplit:
    """The valid records of one split, and the issues of any records that were skipped."""

    split: str
    data_dir: Path
    records: tuple[AvdnRecord, ...]
    #: The skipped records, each with its issues, in file order.
    skipped_records: tuple[SkippedRecord, ...] = field(default=())

    def __repr__(self) -> str:
        # Short, for notebooks: the default repr printed every record with its arrays
        # (68 KB for the sample's 40 training records).
        skipped = f", {len(self.skipped_records)} skipped" if self.skipped_records else ""
        return (
            f"AvdnSplit({self.split!r}, {len(self.records)} records{skipped}, "
            f"{len(self.map_names())} maps, from {str(self.data_dir)!r})"
        )

    @property
    def annotation_path(self) -> Path:
        return self.data_dir / ANNOTATIONS_DIR / annotation_file_name(self.split)

    @property
    def images_dir(self) -> Path:
        return self.data_dir / IMAGES_DIR

    @property
    def skipped(self) -> tuple[ValidationIssue, ...]:
        """The issues of the skipped records, in file order."""
        return tuple(issue for s in self.skipped_records for issue in s.issues)

    @property
    def skipped_record_indices(self) -> list[int]:
        return [s.record_index for s in self.skipped_records]

    @property
    def ground_truth_withheld(self) -> bool:
        """True when no record has more than the start view (the real test_unseen)."""
        return bool(self.records) and not any(r.has_ground_truth for r in self.records)

    def map_names(self) -> list[str]:
        return sorted({r.map_name for r in self.records})

    def trajectories(self) -> dict[TrajectoryKey, tuple[AvdnRecord, ...]]:
        """Records grouped by (map_name, trajectory index) and sorted by round."""
        return group_trajectories(self.records)

    def episodes(self, mode: EpisodeMode = "andh", skip_incomplete: bool = False) -> list[Episode]:
        """ANDH: one episode per record (file order). ANDH-Full: one per trajectory.

        A trajectory with missing or skipped rounds cannot form an ANDH-Full episode: it
        raises, or with ``skip_incomplete`` is left out (see :func:`build_episodes`).
        """
        episodes, issues = build_episodes(
            self.records, self.split, mode, str(self.annotation_path), self.skipped_records
        )
        if issues and not skip_incomplete:
            hint = "leave these trajectories out: `skip_incomplete=True` with episodes()"
            raise AvdnValidationError(issues, hint)
        return episodes

    def require_ground_truth(self) -> None:
        """Raise :class:`NoGroundTruthError` if any record lacks a ground-truth path."""
        missing = [r.episode_id for r in self.records if not r.has_ground_truth]
        if missing:
            raise NoGroundTruthError(self.split, missing)


def group_trajectories(
    records: Iterable[AvdnRecord],
) -> dict[TrajectoryKey, tuple[AvdnRecord, ...]]:
    """Group by (map_name, trajectory index), rounds ascending, keys in a stable order."""
    groups: dict[TrajectoryKey, list[AvdnRecord]] = defaultdict(list)
    for record in records:
        groups[(record.map_name, record.trajectory_index)].append(record)
    ordered = sorted(groups, key=lambda key: (key[0], int(key[1])))
    return {key: tuple(sorted(groups[key], key=lambda r: r.round_index)) for key in ordered}


def build_episodes(
    records: Sequence[AvdnRecord],
    split: str,
    mode: EpisodeMode,
    file: str = "<records>",
    skipped: Sequence[SkippedRecord] = (),
) -> tuple[list[Episode], list[ValidationIssue]]:
    """Episodes of a split in either mode, plus issues for incomplete trajectories.

    ANDH-Full needs every round of a trajectory: one that is missing, or that was
    ``skipped`` as invalid, leaves the trajectory out with an issue naming the round.
    Without ``last_round_idx`` the final round is only known as the highest one present,
    so an invalid record whose trajectory cannot be read (its route_index, or its map,
    unreadable) might be that final round: the trajectories it could belong to (of its
    map, or any map when that is unreadable; of its trajectory number, or any when that is
    unreadable) are left out too, rather than scored against a wrong target.
    """
    if mode == "andh":
        return [Episode(split=split, mode="andh", records=(r,)) for r in records], []
    if mode != "andh-full":
        raise ConfigError(f"unknown episode mode {mode!r}; use 'andh' or 'andh-full'")
    placed: dict[TrajectoryKey, list[SkippedRecord]] = defaultdict(list)
    unplaced: list[SkippedRecord] = []
    for s in skipped:
        if s.map_name is not None and s.trajectory_index is not None:
            placed[(s.map_name, s.trajectory_index)].append(s)
        else:
            unplaced.append(s)
    episodes: list[Episode] = []
    issues: list[ValidationIssue] = []
    for (map_name, traj), rounds in group_trajectories(records).items():
        problems = _incomplete_trajectory(
            rounds, placed.get((map_name, traj), []), unplaced, (map_name, traj)
        )
        if problems:
            issues.append(
                ValidationIssue(
                    file,
                    f"trajectory {map_name}/{traj} {'; '.join(problems)}; "
                    "it cannot form an ANDH-Full episode",
                    episode_id=rounds[0].episode_id,
                    field="route_index",
                )
            )
            continue
        episodes.append(Episode(split=split, mode="andh-full", records=rounds))
    return episodes, issues


def _incomplete_trajectory(
    rounds: Sequence[AvdnRecord],
    invalid: Sequence[SkippedRecord],
    unplaced: Sequence[SkippedRecord],
    trajectory: TrajectoryKey,
) -> list[str]:
    """Why a trajectory's valid ``rounds`` are not the whole trajectory (none if they are),
    naming the records (episode ids) that say so."""
    present = {r.round_index for r in rounds}
    invalid_rounds = {s.round_index for s in invalid if s.round_index is not None}
    declaring: dict[int, list[str]] = defaultdict(list)  # last_round_idx -> records giving it
    for r in rounds:
        if r.last_round_idx is not None:
            declaring[r.last_round_idx].append(r.episode_id)
    expected = max(declaring) if declaring else max(present | invalid_rounds)
    problems = []
    if len(declaring) > 1:  # one trajectory has one number of rounds: all but one are wrong
        said = "; ".join(f"{n} in {', '.join(ids)}" for n, ids in sorted(declaring.items()))
        problems.append(f"has rounds that disagree on last_round_idx ({said})")
    missing = _missing_rounds(expected, present | invalid_rounds)
    if missing:
        declared = f"last_round_idx {expected} in {declaring[expected][0]}; " if declaring else ""
        held = ", ".join(r.episode_id for r in rounds)
        problems.append(f"is missing round(s) {missing} ({declared}it holds {held})")
    for s in sorted(invalid, key=lambda s: (s.round_index or 0, s.record_index)):
        problems.append(
            f"round {s.round_index} (record {s.record_index}) was left out as invalid ({s.reason})"
        )
    if not declaring:
        # An invalid record could be this trajectory's final round when what it names
        # (map, trajectory) does not rule it out.
        map_name, traj = trajectory
        unknown = [
            s.record_index
            for s in unplaced
            if s.map_name in (None, map_name) and s.trajectory_index in (None, traj)
        ]
        if unknown:
            problems.append(
                f"has no last_round_idx, and invalid record(s) {unknown} of unreadable "
                "trajectory could be its final round"
            )
    return problems


def _missing_rounds(expected: int, have: set[int]) -> str | None:
    """'2, 5-9' for the rounds 1..expected not in ``have`` (None if none). Spans, not
    rounds: a wrong last_round_idx of 10^12 is told in a few characters (a count of
    999999999988 more rounds named no one), and only the rounds held are looked at."""
    spans = []
    start = 1
    for k in [*sorted(k for k in have if 1 <= k <= expected), expected + 1]:
        if k > start:
            spans.append(str(start) if k - 1 == start else f"{start}-{k - 1}")
        start = k + 1
    return ", ".join(spans) or None


class RepeatedKeys(dict[str, Any]):
    """A JSON object that gave some key more than once (``repeated``): JSON keeps the last
    value, silently; the validation refuses the record, naming the keys."""

    repeated: tuple[str, ...] = ()


def object_keeping_repeats(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' object hook: a plain dict, or a :class:`RepeatedKeys` that says which
    keys came more than once."""
    made = dict(pairs)
    if len(made) == len(pairs):
        return made
    seen: set[str] = set()
    repeated: dict[str, None] = {}
    for key, _ in pairs:
        if key in seen:
            repeated[key] = None
        seen.add(key)
    out = RepeatedKeys(made)
    out.repeated = tuple(repeated)
    return out


_MAYBE_TINY_NUMBER = re.compile(rb"[eE]-0*[1-9][0-9]{2,}|0{100,}")


def read_annotation_file(path: Path) -> list[object]:
    """Decode an annotation file; raises :class:`AvdnFileError` unless it is a JSON list."""
    if not path.is_file():
        raise AvdnFileError(str(path), "annotation file not found")
    raw = path.read_bytes()
    # Only a file that may hold a number too small for a float is read with the slower
    # per-number hook: such a number needs over 160 in exponent and leading zeros
    # together, so it has a three-digit negative exponent or a run of 100 zeros.
    tiny = read_json_float if _MAYBE_TINY_NUMBER.search(raw) else None
    try:
        data = json.loads(raw, object_pairs_hook=object_keeping_repeats, parse_float=tiny)
    except json.JSONDecodeError as exc:
        raise AvdnFileError(
            str(path), f"not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from exc
    except UnicodeDecodeError as exc:
        where = f"{undecodable_at(raw, exc)}{_undecodable_record(raw)}"
        raise AvdnFileError(str(path), f"not UTF-8 text ({exc.reason}): {where}") from exc
    except ValueError as exc:  # Python reads no integer of more than 4,300 digits
        reason = str(exc).split(";")[0]  # its advice (set_int_max_str_digits) is not ours
        raise AvdnFileError(str(path), f"cannot be read: {reason}") from exc
    if not isinstance(data, list):
        kind = type(data).__name__.replace("dict", "object")
        raise AvdnFileError(str(path), f"expected a JSON list of records, got a JSON {kind}")
    return data


def _undecodable_record(raw: bytes) -> str:
    """`` in record i, field f`` where the first text that is not UTF-8 is (AVDN files are
    one line: a byte offset alone leaves a user searching), else ``""``."""
    try:
        data = json.loads(raw.decode("utf-8", "surrogateescape"))
    except ValueError:
        return ""
    if not isinstance(data, list):
        return ""
    for index, record in enumerate(data):
        field = _undecodable_field(record)
        if field is not None:
            return f" in record {index}{f', field {field!r}' if field else ''}"
    return ""


def _undecodable_field(value: Any, at: str = "") -> str | None:
    """The dotted path of the first string in ``value`` holding an undecodable byte (kept
    as a lone surrogate), ``None`` when there is none."""
    if isinstance(value, str):
        return at if any("\udc80" <= c <= "\udcff" for c in value) else None
    if isinstance(value, dict):
        for key, item in value.items():
            name = f"{at}.{key}" if at else str(key)
            found = _undecodable_field(key, name) or _undecodable_field(item, name)
            if found is not None:
                return found
    if isinstance(value, list):
        for i, item in enumerate(value):
            found = _undecodable_field(item, f"{at}[{i}]")
            if found is not None:
                return found
    return None


def _missing_map_issues(
    records: Sequence[AvdnRecord], images_dir: Path, file: str, indices: Sequence[int]
) -> list[ValidationIssue]:
    exists: dict[str, bool] = {}
    issues = []
    for record, index in zip(records, indices, strict=True):
        if record.map_name not in exists:
            exists[record.map_name] = map_image_path(images_dir, record.map_name).is_file()
        if not exists[record.map_name]:
            issues.append(
                ValidationIssue(
                    file,
                    f"map image {map_image_path(images_dir, record.map_name)} not found",
                    index,
                    record.episode_id,
                    "map_name",
                )
            )
    return issues


def check_split(
    data_dir: str | Path, split: str, check_map_images: bool = True
) -> tuple[list[AvdnRecord], list[ValidationIssue]]:
    """Every valid record of a split and every issue found, without raising on records."""
    checked = check_split_indexed(data_dir, split, check_map_images)
    return checked.records, checked.issues


class SplitCheck(NamedTuple):
    """What checking a split found: each valid record's index in the file (for issues
    found later about a record, such as its map image's), the valid records, every issue,
    and the records left out."""

    indices: list[int]
    records: list[AvdnRecord]
    issues: list[ValidationIssue]
    skipped: list[SkippedRecord]


def check_split_indexed(
    data_dir: str | Path, split: str, check_map_images: bool = True
) -> SplitCheck:
    """:func:`check_split`, with the records' indices and the records left out."""
    return SplitCheck(*_check_split(data_dir, split, check_map_images))


def andh_full_notes(checked: SplitCheck, split: str, file: str) -> list[ValidationIssue]:
    """Trajectories of a checked split that cannot form an ANDH-Full episode (rounds
    missing or left out, or disagreeing on last_round_idx), each on its first record.

    Notes, not problems: AVDN's ANDH takes each record alone, and a split may hold
    only some rounds of a trajectory; only ANDH-Full needs them all (AVDN.md).
    """
    index_of = {r.episode_id: i for i, r in zip(checked.indices, checked.records, strict=True)}
    _, incomplete = build_episodes(checked.records, split, "andh-full", file, checked.skipped)
    notes = []
    for issue in incomplete:
        field = "last_round_idx" if "last_round_idx " in issue.message else "route_index"
        message = f"{issue.message} (ANDH episodes are unaffected)"
        record = index_of.get(issue.episode_id or "")
        notes.append(ValidationIssue(file, message, record, issue.episode_id, field))
    return notes


def _check_split(
    data_dir: str | Path, split: str, check_map_images: bool
) -> tuple[list[int], list[AvdnRecord], list[ValidationIssue], list[SkippedRecord]]:
    if split not in SPLITS:
        raise ConfigError(f"unknown split {split!r}; choose one of {', '.join(SPLITS)}")
    data_dir = Path(data_dir)
    path = data_dir / ANNOTATIONS_DIR / annotation_file_name(split)
    data = read_annotation_file(path)
    indices, records, issues = parse_records_indexed(data, str(path), split)
    if check_map_images:
        map_issues = _missing_map_issues(records, data_dir / IMAGES_DIR, str(path), indices)
        if map_issues:
            bad = {i.record_index for i in map_issues}
            kept = [(i, r) for r, i in zip(records, indices, strict=True) if i not in bad]
            indices, records = [i for i, _ in kept], [r for _, r in kept]
            issues = sorted(issues + map_issues, key=lambda i: i.record_index or 0)
    return indices, records, issues, _skipped_records(data, issues)


def _skipped_records(
    data: Sequence[object], issues: Sequence[ValidationIssue]
) -> list[SkippedRecord]:
    by_record: dict[int, list[ValidationIssue]] = defaultdict(list)
    for issue in issues:
        # Every record issue has its index; a file-level issue raises before this point.
        if issue.record_index is not None:
            by_record[issue.record_index].append(issue)
    skipped = []
    for index in sorted(by_record):
        map_name, traj, round_index = record_place(data[index])
        skipped.append(SkippedRecord(index, map_name, traj, round_index, tuple(by_record[index])))
    return skipped


def load_split(
    data_dir: str | Path,
    split: str,
    *,
    skip_invalid: bool = False,
    check_map_images: bool = True,
) -> AvdnSplit:
    """Load and validate one split of an AVDN-format dataset.

    Raises :class:`AvdnValidationError` listing every problem, unless ``skip_invalid``:
    then invalid records are left out and described in ``AvdnSplit.skipped`` (issues) and
    ``AvdnSplit.skipped_records``.
    """
    _, records, issues, skipped = _check_split(data_dir, split, check_map_images)
    if issues and not skip_invalid:
        raise AvdnValidationError(issues)
    return AvdnSplit(
        split=split,
        data_dir=Path(data_dir),
        records=tuple(records),
        skipped_records=tuple(skipped),
    )
