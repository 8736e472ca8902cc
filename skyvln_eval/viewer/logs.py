"""Find the run MCAPs of a run directory and stream one, message by message.

A run directory keeps one run MCAP per episode at ``logs/<split>/<episode_id>.mcap``
(:mod:`skyvln_eval.harness.run`). Selecting episodes looks those paths up directly, so
picking one episode of a 400-episode run opens one file. :class:`RunLogStream` reads a
log through its index, one chunk at a time with its CRC checked, and decodes one message
at a time: the images of an episode are never all in memory together.
"""

from __future__ import annotations

import difflib
import json
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

from mcap.reader import SeekingReader, make_reader

from skyvln_eval.avdn.records import Episode
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import (
    DECODE_ERRORS,
    LogChannel,
    McapLog,
    check_file_framing,
    episode_from_log,
)
from skyvln_eval.errors import (
    ConfigError,
    DataError,
    FormatVersionError,
    McapLogError,
    SkyvlnError,
)

LOGS_DIR = "logs"
_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]*")


@dataclass(frozen=True)
class EpisodeLogRef:
    """One episode's run MCAP: where it is, its split and its episode id."""

    path: Path
    split: str
    episode_id: str

    @property
    def key(self) -> str:
        return f"{self.split}/{self.episode_id}"

    @property
    def run_name(self) -> str:
        """The name of the run directory holding the log (``<run>/logs/<split>/``), or
        '' for a log elsewhere."""
        return self.path.parents[2].name if self.path.parent.parent.name == LOGS_DIR else ""


def _ref(path: Path) -> EpisodeLogRef:
    return EpisodeLogRef(path, path.parent.name, path.stem)


def _parse_selector(selector: str) -> tuple[str | None, str]:
    """``ID`` or ``SPLIT/ID``; names only (no path tricks such as ``..``)."""
    split, _, episode_id = selector.rpartition("/")
    for part in (split, episode_id) if split else (episode_id,):
        if not _SAFE_NAME.fullmatch(part):
            raise ConfigError(f"--episode {selector!r} is not an episode id or SPLIT/EPISODE_ID")
    return (split or None), episode_id


def find_episode_logs(target: str | Path, episodes: Sequence[str] = ()) -> list[EpisodeLogRef]:
    """The run MCAPs to show: ``target`` is a run directory, a folder of them (as
    ``reproduce`` writes a system's splits, ``runs/<system>``) or one ``.mcap`` file.

    ``episodes`` selects by ``ID`` or ``SPLIT/ID``; empty means every episode of the run, in
    (split, episode) order. An id that matches nothing is an error that lists close ids. A
    file holds one episode: a selector naming another is an error, never ignored.
    """
    target = Path(target)
    if target.is_file():
        if target.suffix != ".mcap":
            raise ConfigError(
                f"{target}: not a run directory, a folder of run directories or an .mcap run log"
            )
        with RunLogStream(target) as log:  # a lone file: its split and id from its metadata
            meta = log.metadata.get(t.EPISODE_METADATA, {})
        ref = EpisodeLogRef(target, meta.get("split") or "-", meta.get("episode_id") or target.stem)
        for selector in episodes:
            _check_holds(ref, selector)
        return [ref]
    log_dirs = _log_dirs(target)
    if not episodes:
        found = [p for logs in log_dirs for p in sorted(logs.glob("*/*.mcap"))]
        if not found:
            raise ConfigError(
                f"{target}: the run has no run MCAPs under {LOGS_DIR}/"
                + _raised_before_logging(log_dirs, None, None)
            )
        return [_ref(p) for p in found]
    refs: list[EpisodeLogRef] = []
    for selector in episodes:
        split, episode_id = _parse_selector(selector)
        hits = [p for logs in log_dirs for p in _lookup(logs, split, episode_id)]
        if not hits:
            raise ConfigError(
                _not_found(target, selector, log_dirs)
                + _raised_before_logging(log_dirs, split, episode_id)
            )
        refs += [_ref(p) for p in hits if _ref(p) not in refs]
    return refs


def unlogged_note(target: str | Path) -> str | None:
    """For a run directory (or a folder of them) shown whole: the episodes its rows say
    ended in error before writing a run log, which no recording can show; None when there
    are none (or ``target`` is a file)."""
    target = Path(target)
    if target.is_file():
        return None
    said = _raised_before_logging(_log_dirs(target), None, None)
    return said.removeprefix("; ") or None


def _raised_before_logging(
    log_dirs: Sequence[Path], split: str | None, episode_id: str | None
) -> str:
    """What the run's rows say of episodes (all, or the one selected) that ended in error
    before their run log was written: '' when none did (or the rows cannot be read)."""
    from skyvln_eval.harness.store import RESULTS_FILE
    from skyvln_eval.metrics import read_results

    raised = []
    for logs in log_dirs:
        try:
            rows = read_results(logs.parent / RESULTS_FILE, allow_incomplete=True)
        except SkyvlnError:
            continue
        raised += [
            r
            for r in rows
            if r.status == "error"
            and episode_id in (None, r.episode_id)
            and split in (None, r.split)
            and not (logs / r.split / f"{r.episode_id}.mcap").is_file()
        ]
    if not raised:
        return ""
    first = raised[0]
    why = (first.error or "error").splitlines()[0]
    return (
        f"; {len(raised)} episode(s) ended in error before writing one, e.g. "
        f"{first.split}/{first.episode_id}: {why}"
    )


def _log_dirs(target: Path) -> list[Path]:
    """The ``logs/`` folders of the runs ``target`` stands for: its own (a run directory),
    else those of the run directories in it, resolved as :func:`run_results` resolves a
    folder, so that a reproduce system's folder (``runs/full``) is viewed as it is read."""
    from skyvln_eval.harness.run_reading import run_directories

    if (target / LOGS_DIR).is_dir():  # the logs are all a recording needs
        return [target / LOGS_DIR]
    try:
        runs = run_directories(target)
    except DataError as error:
        raise ConfigError(f"{error}; view also takes one run .mcap log or an .rrd") from None
    found = [run / LOGS_DIR for run in runs if (run / LOGS_DIR).is_dir()]
    if not found:
        raise ConfigError(
            f"{target}: the run has no run MCAPs under {LOGS_DIR}/"
            + _raised_before_logging([run / LOGS_DIR for run in runs], None, None)
        )
    return found


def _lookup(logs: Path, split: str | None, episode_id: str) -> list[Path]:
    """The run MCAPs of one selector in one ``logs/`` folder: direct lookups (one stat per
    split), never a listing of every log of the run."""
    splits = [split] if split else sorted(p.name for p in logs.iterdir() if p.is_dir())
    return [p for p in (logs / s / f"{episode_id}.mcap" for s in splits) if p.is_file()]


def _check_holds(ref: EpisodeLogRef, selector: str) -> None:
    """Refuse ``--episode selector`` for the one-episode file of ``ref`` unless it names
    that episode: recording the file's own episode instead would show the wrong one."""
    split, episode_id = _parse_selector(selector)
    if episode_id != ref.episode_id or split not in (None, ref.split):
        raise ConfigError(
            f"{ref.path} holds episode {ref.key}, not {selector!r}: one .mcap file holds one "
            "episode, so --episode can only name that one; to pick episodes, give the run "
            "directory (its logs/<split>/<episode_id>.mcap)"
        )


def _not_found(target: Path, selector: str, log_dirs: Sequence[Path]) -> str:
    logs = [p for folder in log_dirs for p in folder.glob("*/*.mcap")]
    known = sorted({p.stem for p in logs})
    episode_id = selector.rpartition("/")[2]
    elsewhere = sorted({f"{p.parent.name}/{p.stem}" for p in logs if p.stem == episode_id})
    if elsewhere:  # the id is there, under another split
        hint = f" It is there as {', '.join(elsewhere)}."
    else:
        close = difflib.get_close_matches(episode_id, known, n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
    return f"{target}: no run MCAP for episode {selector!r}.{hint} ({len(known)} episode(s) in it)"


class RunLogStream:
    """A run (or episode) MCAP opened for streaming; use it as a context manager.

    ``metadata`` holds the metadata records; :meth:`episode` rebuilds the episode from
    them (format and schema versions checked); :meth:`messages` yields ``(topic,
    log_time_ns, decoded JSON)`` in log-time order, reading one chunk at a time.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: BinaryIO | None = None
        self._reader: SeekingReader | None = None
        self.metadata: dict[str, dict[str, str]] = {}
        self.topic_counts: dict[str, int] = {}
        self._channels: tuple[LogChannel, ...] = ()

    def __enter__(self) -> RunLogStream:
        try:
            self._file = self.path.open("rb")
        except OSError as error:
            raise McapLogError(str(self.path), f"cannot open: {error.strerror}") from error
        try:
            # The ends and the CRCs the reader does not check first: a cut or foreign file
            # makes the reader fail with no word of why, and a changed byte outside the
            # chunks passed (a recording made from a damaged log without a word).
            check_file_framing(self._file, str(self.path))
            reader = make_reader(self._file, validate_crcs=True)
            if not isinstance(reader, SeekingReader):  # a regular file always seeks
                raise McapLogError(str(self.path), "not a seekable file")
            self._reader = reader
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise McapLogError(str(self.path), "no summary section: an unfinished MCAP file")
            self.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            channels = summary.channels
            counts = summary.statistics.channel_message_counts
            self.topic_counts = {
                channels[cid].topic: n for cid, n in counts.items() if cid in channels and n
            }
            self._channels = tuple(
                LogChannel(
                    c.id,
                    c.topic,
                    c.message_encoding,
                    summary.schemas[c.schema_id].name,
                    summary.schemas[c.schema_id].encoding,
                    summary.schemas[c.schema_id].data,
                    dict(c.metadata),
                )
                for c in channels.values()
                if c.schema_id in summary.schemas
            )
        except McapLogError:
            self.close()
            raise
        except (*DECODE_ERRORS, OSError) as error:  # OSError: a seek the footer sent astray
            self.close()
            raise self._damaged(error) from error
        self._check_run_format()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
        self._file = None
        self._reader = None

    def _check_run_format(self) -> None:
        run = self.metadata.get(t.RUN_METADATA)
        if run is None:
            return  # an episode log (no run): it shows the ground truth only
        if run.get("format") != t.RUN_FORMAT:
            raise McapLogError(str(self.path), f"run format is {run.get('format')!r}")
        if run.get("version") != str(t.RUN_FORMAT_VERSION):
            raise FormatVersionError(
                str(self.path),
                run.get("version"),
                t.RUN_FORMAT_VERSION,
                "View it with the skyvln-eval version that wrote it, or run the episode again.",
            )

    @property
    def run_metadata(self) -> dict[str, str]:
        return self.metadata.get(t.RUN_METADATA, {})

    def episode(self) -> Episode:
        """The episode, from the log's metadata (no message is read)."""
        log = McapLog(str(self.path), "", "", self._channels, (), self.metadata)
        return episode_from_log(log)

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, Any]]:
        """``(topic, log_time_ns, message)`` in log-time order, decoded one at a time."""
        if self._reader is None:
            raise McapLogError(str(self.path), "the log is not open (use it in a with block)")
        try:
            for _, channel, message in self._reader.iter_messages(
                topics=list(topics) if topics is not None else None, log_time_order=True
            ):
                yield channel.topic, message.log_time, json.loads(message.data)
        except (*DECODE_ERRORS, OSError) as error:
            raise self._damaged(error) from error

    def _damaged(self, error: BaseException) -> McapLogError:
        return McapLogError(str(self.path), f"damaged MCAP file: {type(error).__name__}: {error}")
