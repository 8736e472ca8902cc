"""Convert a whole split: one episode log per episode plus the split's manifest.

Output layout: ``OUT/<split>/<mode>/<episode_id>.mcap``,
``OUT/<split>/<mode>/manifest.parquet`` and ``left_out.json`` beside it (the records,
trajectories and episodes that have no log, and why). Work is grouped by map (each map image is read
once per group) and spread over ``workers`` processes; every file is a pure function of
its episode, its map and the options, so the output is byte-identical whatever the
number of workers.

A re-run skips an episode whose file was made from the same input (same records, map
image, options, toolkit and format versions: the ``input_sha256``) and is whole. The
quick check: the split's manifest recorded that input and these exact bytes (size and
SHA-256), so the file need not be parsed. Without such a record (a conversion cut short
before its manifest) or when the bytes differ, the file must read back without any
error and carry that ``input_sha256`` in its conversion metadata. Anything else is
converted again.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Literal, NamedTuple

import skyvln_eval
from skyvln_eval.avdn import (
    Episode,
    EpisodeMode,
    MapGeoref,
    SkippedRecord,
    build_episodes,
    load_map_bgr,
    load_split,
    map_image_path,
    parse_record,
    undefined_fields_note,
)
from skyvln_eval.avdn.constants import IMAGES_DIR
from skyvln_eval.avdn.validation import is_episode_id
from skyvln_eval.converters import topics
from skyvln_eval.converters.convert import (
    DEFAULT_OPTIONS,
    ConvertOptions,
    convert_episode,
    episode_rounds,
)
from skyvln_eval.converters.left_out import LEFT_OUT_NAME, LeftOut, write_left_out
from skyvln_eval.converters.manifest import (
    MANIFEST_NAME,
    ManifestRow,
    episode_file_name,
    gt_lengths_m,
    read_manifest,
    write_manifest,
)
from skyvln_eval.converters.reader import read_log
from skyvln_eval.converters.writer import McapLogWriter
from skyvln_eval.errors import AvdnValidationError, SkyvlnError, ValidationIssue
from skyvln_eval.fileio import (
    ensure_directory,
    ensure_writable_directory,
    exclusive_lock,
    sha256_bytes,
    sha256_file,
)
from skyvln_eval.worlds import WorldTile

Status = Literal["converted", "skipped", "failed"]


class RemovedLog(NamedTuple):
    """A log of an earlier conversion that this one deleted, and the true reason."""

    file_name: str
    reason: str


def split_output_dir(out_dir: str | Path, split: str, mode: str) -> Path:
    return Path(out_dir) / split / mode


@dataclass(frozen=True)
class EpisodeOutcome:
    """What happened to one episode; ``note`` explains a failure or a replaced file."""

    episode_id: str
    status: Status
    row: ManifestRow | None = None
    note: str | None = None


@dataclass(frozen=True)
class MapJob:
    """All episodes of one map, as raw AVDN records (picklable for worker processes)."""

    data_dir: str
    annotation_file: str
    split: str
    mode: EpisodeMode
    map_name: str
    georef: MapGeoref
    episodes: tuple[tuple[dict[str, Any], ...], ...]
    out_dir: str
    options: ConvertOptions
    #: The split's last manifest rows of this map's files, by file name.
    recorded: Mapping[str, ManifestRow] = field(default_factory=dict)


@dataclass
class ConvertReport:
    """The result of converting a split: manifest rows, and what was left out or failed.

    ``invalid`` holds every issue of the ``skipped_records`` (several per record at
    times); ``incomplete`` one issue per ANDH-Full trajectory left out.
    """

    out_dir: Path
    manifest_path: Path
    rows: list[ManifestRow] = field(default_factory=list)
    outcomes: list[EpisodeOutcome] = field(default_factory=list)
    invalid: list[ValidationIssue] = field(default_factory=list)
    skipped_records: list[SkippedRecord] = field(default_factory=list)
    incomplete: list[ValidationIssue] = field(default_factory=list)
    removed_stale: list[RemovedLog] = field(default_factory=list)
    #: MCAP files in the folder that no conversion wrote, left in place.
    foreign_files: list[str] = field(default_factory=list)
    #: A note on record fields the AVDN format does not define (kept in the logs as they
    #: are), with the field each may misspell; None when there are none.
    undefined_fields_note: str | None = None

    @property
    def left_out_path(self) -> Path:
        return self.out_dir / LEFT_OUT_NAME

    def count(self, status: Status) -> int:
        return sum(1 for o in self.outcomes if o.status == status)

    @property
    def failed(self) -> list[EpisodeOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    def left_out(self) -> list[LeftOut]:
        """Everything without a log: invalid records, incomplete trajectories, failures."""
        return [
            *(
                LeftOut("invalid_record", s.episode_id, s.record_index, s.reasons)
                for s in self.skipped_records
            ),
            *(
                LeftOut("incomplete_trajectory", i.episode_id, None, (i.message,))
                for i in self.incomplete
            ),
            *(
                LeftOut("failed_episode", o.episode_id, None, (o.note or "failed",))
                for o in self.failed
            ),
        ]


#: What a converted file holds for the same input and format version, changed whenever
#: that changes, so a re-run converts again instead of keeping the old file (2: an
#: ANDH-Full ground truth holds a view two rounds share once).
CONVERSION_REVISION: Final = 2


def input_fingerprint(
    raw_records: Sequence[dict[str, Any]],
    split: str,
    mode: str,
    map_sha256: str,
    options: ConvertOptions,
) -> str:
    """SHA-256 of everything a converted file depends on."""
    payload = {
        "format_version": topics.EPISODE_FORMAT_VERSION,
        "revision": CONVERSION_REVISION,
        "toolkit_version": skyvln_eval.__version__,
        "split": split,
        "mode": mode,
        "records": list(raw_records),
        "map_image_sha256": map_sha256,
        "options": options.as_metadata(),
    }
    return sha256_bytes(json.dumps(payload, ensure_ascii=False).encode("utf-8"))


def _existing_row(
    path: Path, fingerprint: str, episode: Episode, recorded: ManifestRow | None
) -> ManifestRow | None:
    """The manifest row of a file that can be skipped, or None to convert again;
    ``recorded`` is the last manifest's row of the file."""
    if not path.is_file():
        return None
    if (
        recorded is not None
        and recorded.input_sha256 == fingerprint
        and recorded.size_bytes == path.stat().st_size
    ):
        digest = sha256_file(path)
        if digest == recorded.sha256:  # the very bytes made from this input
            return _row(episode, path, fingerprint, digest)
    try:
        log = read_log(path)
    except SkyvlnError:
        return None
    if log.metadata.get(topics.CONVERSION_METADATA, {}).get("input_sha256") != fingerprint:
        return None
    return _row(episode, path, fingerprint)


def _recorded_files(manifest: Path) -> dict[str, ManifestRow]:
    """The last manifest's rows by file name; none when there is no readable manifest
    (then every file is read back)."""
    if not manifest.is_file():
        return {}
    try:
        rows = read_manifest(manifest)
    except SkyvlnError:
        return {}
    return {r.file_name: r for r in rows}


def _row(episode: Episode, path: Path, fingerprint: str, digest: str | None = None) -> ManifestRow:
    gt_length, d_net = gt_lengths_m(episode)
    return ManifestRow(
        episode_id=episode.episode_id,
        split=episode.split,
        mode=episode.mode,
        map_name=episode.map_name,
        rounds=episode_rounds(episode),
        gt_views=len(episode.gt_path_corners),
        gt_length_m=gt_length,
        d_net_m=d_net,
        file_name=path.name,
        sha256=sha256_file(path) if digest is None else digest,
        size_bytes=path.stat().st_size,
        input_sha256=fingerprint,
    )


def run_map_job(job: MapJob) -> list[EpisodeOutcome]:
    """Convert (or skip) every episode of one map; failures are reported, not raised."""
    image = map_image_path(Path(job.data_dir) / IMAGES_DIR, job.map_name)
    try:
        map_sha256 = sha256_file(image)
    except OSError as exc:
        note = f"map image {image} cannot be read: {exc}"
        return [EpisodeOutcome(_first_id(raw), "failed", note=note) for raw in job.episodes]
    world: WorldTile | None = None
    map_error: str | None = None  # a map image that does not decode fails every episode once
    outcomes = []
    for raw in job.episodes:
        try:
            episode = Episode(
                job.split,
                job.mode,
                tuple(parse_record(r, job.annotation_file) for r in raw),
            )
            fingerprint = input_fingerprint(raw, job.split, job.mode, map_sha256, job.options)
            path = Path(job.out_dir) / episode_file_name(episode.episode_id)
            row = _existing_row(path, fingerprint, episode, job.recorded.get(path.name))
            if row is not None:
                outcomes.append(EpisodeOutcome(episode.episode_id, "skipped", row))
                continue
            if world is None and (job.options.observations or job.options.map_tile_max_side_px):
                if map_error is not None:
                    outcomes.append(EpisodeOutcome(episode.episode_id, "failed", note=map_error))
                    continue
                try:
                    world = WorldTile(job.map_name, job.georef, load_map_bgr(image, job.georef))
                except SkyvlnError as exc:
                    map_error = str(exc)
                    raise
            with McapLogWriter(path) as writer:
                writer.add_metadata(
                    topics.CONVERSION_METADATA,
                    {"input_sha256": fingerprint, "map_image_sha256": map_sha256},
                )
                convert_episode(episode, world, writer, job.options)
            outcomes.append(
                EpisodeOutcome(episode.episode_id, "converted", _row(episode, path, fingerprint))
            )
        except SkyvlnError as exc:
            outcomes.append(EpisodeOutcome(_first_id(raw), "failed", note=str(exc)))
        except OSError as exc:  # this episode's file only (the folder was checked to take files)
            note = f"its log cannot be written or read: {exc}"
            outcomes.append(EpisodeOutcome(_first_id(raw), "failed", note=note))
    return outcomes


def _first_id(raw: Sequence[dict[str, Any]]) -> str:
    first = raw[0] if raw else {}
    return f"{first.get('map_name', '?')}__{first.get('route_index', '?')}"


def _jobs(
    episodes: Sequence[Episode],
    data_dir: Path,
    annotation_file: str,
    out_dir: Path,
    options: ConvertOptions,
    recorded: Mapping[str, ManifestRow],
) -> list[MapJob]:
    """One job per map; ``recorded``: the last manifest's rows by file name."""
    by_map: dict[str, list[Episode]] = {}
    for episode in episodes:
        by_map.setdefault(episode.map_name, []).append(episode)
    jobs = [
        MapJob(
            data_dir=str(data_dir),
            annotation_file=annotation_file,
            split=group[0].split,
            mode=group[0].mode,
            map_name=map_name,
            georef=group[0].georef,
            episodes=tuple(tuple(r.to_json_dict() for r in e.records) for e in group),
            out_dir=str(out_dir),
            options=options,
            recorded={
                name: recorded[name]
                for name in (episode_file_name(e.episode_id) for e in group)
                if name in recorded
            },
        )
        for map_name, group in by_map.items()
    ]
    # Largest first, so the last job to finish is a small one (balanced workers).
    return sorted(jobs, key=lambda job: (-len(job.episodes), job.map_name))


def _removal_reasons(report: ConvertReport) -> dict[str, str]:
    """Why a log of an earlier run that this run did not write is deleted, by file name.

    It goes even when this run could not convert its episode: it was made from an input
    that is no longer there (a record now invalid, a map image since changed), and a
    folder whose manifest listed it would pass that episode off as this input's.
    """
    reasons: dict[str, str] = {}
    for o in report.failed:
        reasons[episode_file_name(o.episode_id)] = f"this run could not convert it ({o.note})"
    for issue in report.incomplete:
        if issue.episode_id is not None:
            name = episode_file_name(issue.episode_id)
            reasons.setdefault(name, f"its trajectory was left out ({issue.message})")
    for record in report.skipped_records:
        if record.episode_id is not None:
            name = episode_file_name(record.episode_id)
            why = "; ".join(record.reasons)
            reasons.setdefault(
                name, f"its record {record.record_index} was left out as invalid ({why})"
            )
    return reasons


def _remove_stale(
    out_dir: Path, keep: set[str], listed: set[str], reasons: dict[str, str]
) -> tuple[list[RemovedLog], list[str]]:
    """Delete the episode logs of an earlier conversion that this one did not write, and
    temp files; (what was removed, the names of other MCAP files, left in place).

    An earlier conversion's log is one the last manifest ``listed`` or one named as an
    episode log (``<map_name>__<route_index>.mcap``, e.g. of a conversion cut short before
    its manifest). Any other ``.mcap`` (a recording put here by hand) is not this tool's to
    delete; validate reports it as not listed in the manifest.
    """
    removed, foreign = [], []
    for path in sorted(out_dir.glob("*.mcap")):
        if path.name in keep:
            continue
        if path.name in listed or is_episode_id(path.name.removesuffix(".mcap")):
            path.unlink()
            reason = reasons.get(path.name, "not an episode of this split and mode")
            removed.append(RemovedLog(path.name, reason))
        else:
            foreign.append(path.name)
    for tmp in out_dir.glob(".*.mcap.*.tmp"):
        tmp.unlink(missing_ok=True)
    return removed, foreign


def convert_split(
    data_dir: str | Path,
    split: str,
    out_dir: str | Path,
    mode: EpisodeMode = "andh",
    workers: int = 1,
    options: ConvertOptions = DEFAULT_OPTIONS,
    skip_invalid: bool = False,
    on_progress: Callable[[int], None] | None = None,
) -> ConvertReport:
    """Convert one split (see the module docstring); ``on_progress(n)`` after n more episodes."""
    data_dir = Path(data_dir)
    loaded = load_split(data_dir, split, skip_invalid=skip_invalid)
    episodes, incomplete = build_episodes(
        loaded.records, split, mode, str(loaded.annotation_path), loaded.skipped_records
    )
    if incomplete and not skip_invalid:
        raise AvdnValidationError(incomplete)
    # One conversion of a split and mode into a folder at a time: each removes the stale
    # logs and temporary files it finds there, which another's may be (a run converting
    # into the shared cache while `convert` writes the same folder lost logs to it).
    # The folder first: its lock file would otherwise fail on a file of that name, naming
    # neither (an audit: "afile: File exists").
    ensure_directory(out_dir, "output folder")
    with exclusive_lock(Path(out_dir) / f".{split}-{mode}.lock"):
        target = ensure_writable_directory(split_output_dir(out_dir, split, mode), "output folder")
        report = ConvertReport(
            target,
            target / MANIFEST_NAME,
            invalid=list(loaded.skipped),
            skipped_records=list(loaded.skipped_records),
            incomplete=incomplete,
            undefined_fields_note=undefined_fields_note(loaded.records),
        )
        recorded = _recorded_files(report.manifest_path)
        jobs = _jobs(episodes, data_dir, str(loaded.annotation_path), target, options, recorded)
        results: dict[str, EpisodeOutcome] = {}
        for outcomes in _run(jobs, workers):
            for outcome in outcomes:
                results[outcome.episode_id] = outcome
            if on_progress is not None:
                on_progress(len(outcomes))
        report.outcomes = [results[e.episode_id] for e in episodes]
        report.rows = [o.row for o in report.outcomes if o.row is not None]
        report.removed_stale, report.foreign_files = _remove_stale(
            target, {r.file_name for r in report.rows}, set(recorded), _removal_reasons(report)
        )
        # What was left out first, the manifest last: the manifest marks a finished conversion
        # (validate checks the folder against it), so it never stands beside an older list.
        left_out_sha256 = write_left_out(report.left_out_path, split, mode, report.left_out())
        write_manifest(report.manifest_path, report.rows, left_out_sha256)
        return report


def _run(jobs: list[MapJob], workers: int) -> Iterable[list[EpisodeOutcome]]:
    """Each map job's outcomes, as jobs finish; with ``workers`` processes, a job whose
    process died (a crash, the out-of-memory killer) fails its episodes with that note
    and the others go on."""
    if workers <= 1 or len(jobs) <= 1:
        return map(run_map_job, jobs)
    # Imported here: the harness package imports this module.
    from skyvln_eval.harness.executors import ProcessExecutor, WorkerDied

    def results() -> Iterator[list[EpisodeOutcome]]:
        for job, outcome in ProcessExecutor(min(workers, len(jobs))).map_unordered(
            run_map_job, jobs
        ):
            if isinstance(outcome, WorkerDied):
                note = f"the process converting map {job.map_name} ended: {outcome}"
                yield [EpisodeOutcome(_first_id(raw), "failed", note=note) for raw in job.episodes]
            elif isinstance(outcome, BaseException):
                raise outcome
            else:
                yield outcome

    return results()
