"""Run a configuration over its episodes: resumably, on any executor, with progress.

A run directory holds:

- ``config.yaml``: the resolved :class:`RunConfig` (a directory never mixes two configs);
- ``versions.json``: toolkit and library versions and git revision, of each launch that
  found other code than the last (:mod:`.provenance`);
- ``results.jsonl``: one :class:`EpisodeResult` per episode, appended as episodes finish
  (:mod:`.store`), so ``skyvln-eval score`` works on it directly;
- ``logs/<split>/<episode_id>.mcap``: the run MCAP of each episode;
- ``control/<split>/<episode_id>.parquet``: the control log of each episode (dynamics);
- ``run.json``: the last report: episodes by status, errors, missing episodes, and the
  structured-output level negotiated with each LLM endpoint.

Episodes are read from episode MCAPs, converted once from the dataset into the cache
(:func:`episode_logs`). Running again after a crash or ``kill -9`` runs only the episodes
that have no row; the result rows (and so the scores) are those of an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skyvln_eval.control.registry import controller_config
from skyvln_eval.converters.batch import convert_split
from skyvln_eval.converters.convert import ConvertOptions
from skyvln_eval.converters.reader import check_file_ends, read_episode
from skyvln_eval.errors import (
    AvdnValidationError,
    ConfigError,
    DataError,
    ForeignRowsError,
    McapLogError,
    ResultsWriteError,
)
from skyvln_eval.fileio import (
    atomic_write_json,
    atomic_write_text,
    read_yaml_mapping,
)
from skyvln_eval.harness.config import HOW_IT_RUNS, RunConfig, run_config_from_mapping
from skyvln_eval.harness.executors import Executor, NoWorkerLeft, make_executor
from skyvln_eval.harness.llm_caches import cache_notes
from skyvln_eval.harness.lock import RunDirLock, hold_run_dir, remove_leftover_temporaries
from skyvln_eval.harness.preflight import preflight
from skyvln_eval.harness.provenance import mixed_versions_note, record_launch
from skyvln_eval.harness.runner import (
    CONTROL_DIR,
    LOGS_DIR,
    EpisodeTask,
    control_log_name,
    failed_result,
    log_path,
    run_episode_task,
)
from skyvln_eval.harness.store import DAMAGED_FILE, RESULTS_FILE, ResultStore, RowKey, key_of
from skyvln_eval.llm_records import LlmCall
from skyvln_eval.metrics.official import view_success
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.scoring import can_succeed, touched_an_obstacle
from skyvln_eval.paths import cache_root

CONFIG_FILE = "config.yaml"
VERSIONS_FILE = "versions.json"
REPORT_FILE = "run.json"
#: The files a run writes at its top level and the folders of its per-episode files
#: (with their suffixes): the only temporaries a launch may clean up after a killed one.
RUN_FILES = frozenset({CONFIG_FILE, VERSIONS_FILE, REPORT_FILE, RESULTS_FILE, DAMAGED_FILE})
RUN_FOLDERS = {LOGS_DIR: frozenset({".mcap"}), CONTROL_DIR: frozenset({".parquet"})}
#: Episode logs for the harness carry no images: it needs the episode, not its pictures.
EPISODE_LOG_OPTIONS = ConvertOptions(observations=False, map_tile_max_side_px=0)


#: The key of ``run.json`` that records the folder a relative ``data:`` path named.
RELATIVE_DATA_KEY = "relative_data_dir"


def is_synthetic_data(data: str) -> bool:
    """Whether ``data`` names a synthetic dataset (``sample`` / ``full``), built into the
    cache on first use, rather than a folder."""
    return data in ("sample", "full")


def is_relative_data(data: str) -> bool:
    """Whether ``data`` is a folder path relative to the directory a command runs in."""
    return not is_synthetic_data(data) and not Path(data).expanduser().is_absolute()


def read_run_report(run_dir: Path) -> dict[str, Any] | None:
    """The ``run.json`` of ``run_dir`` as written, ``None`` when there is none;
    :class:`ConfigError` naming the file when it is there but is no JSON object."""
    path = run_dir / REPORT_FILE
    if not path.exists():
        return None
    try:
        recorded = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(recorded, dict):
            raise ValueError(f"a JSON {type(recorded).__name__}, not an object")
    except (OSError, ValueError) as error:
        raise ConfigError(f"{path}: cannot be read ({error})") from None
    return recorded


def recorded_data_dir(run_dir: Path) -> Path | None:
    """The folder a relative ``data:`` path named when the run in ``run_dir`` was launched
    (its ``run.json``), if recorded; :class:`ConfigError` naming the file when it is there
    but cannot be read (a damaged record silently lifted the check it is for, and a resume
    then wrote the other folder into it)."""
    try:
        recorded = read_run_report(run_dir)
    except ConfigError as error:
        raise ConfigError(
            f"{error}; it records the folder the run's relative data path named where it "
            "was launched, so the run cannot be checked against it: restore the file, or "
            "give data as an absolute path"
        ) from None
    value = None if recorded is None else recorded.get(RELATIVE_DATA_KEY)
    return Path(value) if isinstance(value, str) else None


def check_same_data(config: RunConfig, data_dir: Path, run_dir: Path) -> None:
    """Refuse to go on with a run whose relative ``data:`` path named another folder when
    it was launched (the same command from another directory would read other data)."""
    before = recorded_data_dir(run_dir) if is_relative_data(config.data) else None
    if before is not None and before != data_dir:
        raise ConfigError(
            f"{run_dir} ran on {before} (data {config.data!r}, a path relative to the "
            f"directory it was launched from); from here {config.data!r} is {data_dir}: "
            "run the command from where it was launched, or give data as an absolute path"
        )


def resolve_data_dir(data: str) -> Path:
    """``"sample"`` / ``"full"`` (synthetic, built on first use) or an AVDN-format folder."""
    if is_synthetic_data(data):
        from skyvln_eval.worlds.sample import ensure_dataset

        return ensure_dataset(data)
    path = Path(data).expanduser()
    if not (path / "annotations").is_dir():
        raise ConfigError(f"data {data!r} is neither 'sample', 'full' nor an AVDN-format folder")
    return path.resolve()


def episode_logs_root(data_dir: Path) -> Path:
    digest = hashlib.sha256(str(data_dir.resolve()).encode()).hexdigest()[:12]
    return cache_root() / "episode-logs" / digest


#: What to do about invalid records met by a run (or reproduce): it runs every episode of
#: its splits, so the dataset has to be fixed (deliberately: a run that skipped records
#: would be scored on another episode set than the split's).
RUN_INVALID_HINT = (
    "a run needs every record of its splits: fix them; `skyvln-eval validate DATA_DIR` lists "
    "every problem, `skyvln-eval summary DATA_DIR --skip-invalid` shows the splits without them"
)


def selected(config: RunConfig, episode_ids: Sequence[str]) -> list[str]:
    """Of one split's episodes (in file order), those the run covers: the listed ones when
    ``episodes`` lists some, the first ``limit`` of them when it sets one. ``score`` checks
    a run's rows against the same selection (:mod:`skyvln_eval.reports.run_coverage`)."""
    wanted = set(config.episodes) if config.episodes is not None else None
    return [e for e in episode_ids if wanted is None or e in wanted][: config.limit]


def episode_logs(config: RunConfig, data_dir: Path) -> dict[RowKey, Path]:
    """The episode MCAP of every episode the run covers, in run order (converted if needed
    into the cache every run on the data shares; the converter takes its turn there).

    An episode the run covers whose log could not be written (its map image unreadable,
    a full disk) stops the run, naming why: left out, it went unseen until scoring, and a
    ``limit`` took the next episode in its place."""
    out: dict[RowKey, Path] = {}
    wanted = set(config.episodes) if config.episodes is not None else None
    found: set[str] = set()  # all of them: a listed episode past the limit exists all the same
    unconverted: list[str] = []
    root = episode_logs_root(data_dir)
    for split in config.splits:
        try:
            report = convert_split(
                data_dir, split, root, config.episode_mode, options=EPISODE_LOG_OPTIONS
            )
        except AvdnValidationError as error:  # a run has no way to leave records out
            raise AvdnValidationError(error.issues, RUN_INVALID_HINT) from None
        files = {row.episode_id: row.file_name for row in report.rows}
        failed = {o.episode_id: o.note for o in report.failed}
        episode_ids = [o.episode_id for o in report.outcomes]
        found.update(episode_ids)
        for episode_id in selected(config, episode_ids):
            if episode_id in failed:
                unconverted.append(f"{split}/{episode_id}: {failed[episode_id]}")
            else:
                out[(split, episode_id)] = report.out_dir / files[episode_id]
    if unconverted:
        raise DataError(
            f"{len(unconverted)} episode(s) of the run could not be converted to episode "
            f"logs (under {root}): " + "; ".join(unconverted[:5])
            + ("; ..." if len(unconverted) > 5 else "")
        )  # fmt: skip
    if wanted is not None:
        unknown = wanted - found
        if unknown:
            shown = ", ".join(sorted(unknown)[:10])
            raise ConfigError(
                f"the run config's episodes: not found in split(s) {', '.join(config.splits)} "
                f"of {config.data!r}: {shown}"
            )
    return out


def prepare_run_dir(config: RunConfig, run_dir: Path) -> None:
    """Create the run directory, or check that it holds a run of this same configuration,
    or of one that selected fewer of the same episodes (:func:`grows`): a quick look with
    ``limit: 3`` goes on to the whole split in place, its episodes kept."""
    path = run_dir / CONFIG_FILE
    if path.exists():
        existing = run_config_from_mapping(read_yaml_mapping(path, "run config"), str(path))
        if existing.digest() != config.digest() and not grows(existing, config):
            raise ConfigError(
                f"{run_dir} holds a run of another configuration ({existing.system!r}, "
                f"{existing.settings_digest()}; {config_differences(existing, config)}); resume it "
                "with that config or use a new run directory (in place, a run may only "
                "grow: a larger or no limit, more episodes listed, all else the same)"
            )
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, config.to_yaml())


def config_differences(before: RunConfig, after: RunConfig, shown: int = 4) -> str:
    """The settings that differ, e.g. "seed 0 here, 1 given" (nested ones by their
    dotted path), the first ``shown`` of them."""
    old, new = _flat(before.model_dump(mode="json")), _flat(after.model_dump(mode="json"))
    names = [k for k in dict.fromkeys([*old, *new]) if old.get(k) != new.get(k)]
    names = [k for k in names if k.split(".")[0] not in HOW_IT_RUNS]
    parts = [f"{k} {old.get(k)!r} here, {new.get(k)!r} given" for k in names[:shown]]
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(parts) + more if parts else "settings differ"


def _flat(data: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(data, dict):
        return {prefix: data}
    out: dict[str, Any] = {}
    for key, value in data.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def grows(before: RunConfig, after: RunConfig) -> bool:
    """Whether ``after`` is ``before`` with a selection holding all of its episodes: the same
    settings but a larger (or no) limit with the same episode list, or a longer (or no)
    episode list without a limit. (Both changed at once, the first N of the longer list
    may leave out an episode of the shorter one's first N.)"""
    selection = {"limit": after.limit, "episodes": after.episodes}
    if before.model_copy(update=selection).digest() != after.digest():
        return False  # something besides the selection differs
    if before.episodes == after.episodes:
        return after.limit is None or (before.limit is not None and after.limit >= before.limit)
    if before.limit is not None or after.limit is not None or before.episodes is None:
        return False
    return after.episodes is None or set(before.episodes) <= set(after.episodes)


def foreign_rows(config: RunConfig, results: Sequence[EpisodeResult]) -> list[str]:
    """The rows among ``results`` that ``config`` did not make, each as "split/episode:
    what differs": another system, execution mode or settings (the selection aside, so
    the rows of a run that grew in place are its own). Rows of older runs that did not
    record their settings are checked on system and mode alone."""
    settings = config.settings_digest()
    legacy = config.legacy_settings_digest()  # official runs recorded before 2026-11-29
    found = []
    for r in results:
        differs = []
        if r.system != config.system:
            differs.append(f"system {r.system!r}, not {config.system!r}")
        mode = r.extra.get("execution_mode")
        if mode is not None and mode != config.mode:
            differs.append(f"execution mode {mode!r}, not {config.mode!r}")
        made = r.extra.get("settings_digest")
        if made is not None and made not in (settings, legacy):
            differs.append(f"settings {made}, not {settings}")
        if differs:
            found.append(f"{r.split}/{r.episode_id}: {'; '.join(differs)}")
    return found


#: The bytes a parquet file starts and ends with.
_PARQUET_MAGIC = b"PAR1"


def file_damage(path: Path) -> str | None:
    """Why the episode file ``path`` (a run MCAP or a control parquet) cannot be kept:
    missing, or cut short (its closing magic gone), read from its two ends only; None when
    it looks whole. A resume runs its episode again: counted done, the file stayed bad."""
    if not path.is_file():
        return "missing"
    if path.suffix == ".mcap":
        try:
            with path.open("rb") as handle:
                check_file_ends(handle, path.name)
        except McapLogError as error:
            return f"damaged: {str(error).removeprefix(f'{path.name}: ')}"
        return None
    with path.open("rb") as handle:
        head = handle.read(len(_PARQUET_MAGIC))
        size = handle.seek(0, io.SEEK_END)
        handle.seek(max(0, size - len(_PARQUET_MAGIC)))
        tail = handle.read()
    if head != _PARQUET_MAGIC or tail != _PARQUET_MAGIC or size < 3 * len(_PARQUET_MAGIC):
        return "damaged: truncated or not a parquet file"
    return None


def episode_files(config: RunConfig, run_dir: Path, row: EpisodeResult) -> list[Path]:
    """The files a recorded episode keeps: its run MCAP (when the run writes logs) and,
    flown, its control log."""
    wanted = [log_path(run_dir, row.split, row.episode_id)] if config.write_logs else []
    if row.control is not None:
        wanted.append(run_dir / control_log_name(row.split, row.episode_id))
    return wanted


def lost_files(
    config: RunConfig, run_dir: Path, store: ResultStore, keys: Sequence[RowKey]
) -> dict[RowKey, str]:
    """Of the recorded episodes ``keys``, those whose run MCAP (when the run writes logs)
    or control log (a flown episode) is missing or cut short, with the first such file and
    what is wrong with it: a resume would otherwise count them done with their logs lost.
    Error rows are left be (an episode that raised wrote none; ``--retry-failed`` runs
    them again)."""
    lost: dict[RowKey, str] = {}
    for key in keys:
        row = store.get(key)
        if row is None or row.status == "error":
            continue
        for path in episode_files(config, run_dir, row):
            damage = file_damage(path)
            if damage is not None:
                lost[key] = f"{path.relative_to(run_dir)}: {damage}"
                break
    return lost


def check_own_rows(config: RunConfig, results: Sequence[EpisodeResult], where: Path) -> None:
    """Refuse results of which some rows another configuration made: resumed or scored,
    they would pass for this run's (a row copied in, a config.yaml replaced)."""
    foreign = foreign_rows(config, results)
    if foreign:
        raise ForeignRowsError(
            f"{where}: {len(foreign)} of its {len(results)} result row(s) were made by "
            f"another configuration than its {CONFIG_FILE}, e.g. {foreign[0]}; a run "
            "directory holds the rows of one configuration: use a new run directory, or "
            f"put back the {CONFIG_FILE} that made them"
        )


@dataclass
class RunReport:
    """What a run covers and what happened: episodes by status, errors, missing episodes.

    ``statuses`` counts the latest row of every expected episode by status (``ok``,
    ``degraded``, ``error``); ``errors`` holds the first line of each error episode's error.
    ``stopped`` says why the run stopped before its end (e.g. refused credentials).
    ``simulated_s`` is the time flown by the episodes run now (dynamics mode only);
    ``flights`` counts, of the flown episodes recorded, those that crashed (a step that
    touched an obstacle) and those with control steps whose solve failed (the controller fell
    back): outcomes the statuses, which judge the agent, do not show. ``finished`` is
    false from a launch until its end: a ``run.json`` that says so is of a launch that was
    stopped (Ctrl-C, a kill) with ``missing`` the episodes it had still to run.
    """

    run_dir: Path
    system: str
    expected: list[RowKey]
    ran_now: int = 0
    already_done: int = 0
    statuses: dict[str, int] = field(default_factory=dict)
    errors: dict[RowKey, str] = field(default_factory=dict)
    missing: list[RowKey] = field(default_factory=list)
    wall_s: float = 0.0
    simulated_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    structured_output: dict[str, str] = field(default_factory=dict)
    server_defaults: dict[str, str] = field(default_factory=dict)
    stopped: str | None = None
    flights: dict[str, int] = field(default_factory=dict)
    finished: bool = False
    #: How many runs shared the pass ``wall_s`` measures (a reproduction runs several
    #: together, their episodes interleaved: no run has a wall time of its own).
    runs_in_pass: int = 1
    #: The folder a relative ``data:`` path named when the run was launched (it depends
    #: on the directory the command ran in); None for other data.
    data_dir: str | None = None

    @property
    def complete(self) -> bool:
        return not self.missing

    @property
    def recorded(self) -> int:
        return sum(self.statuses.values())

    @property
    def error_share(self) -> float:
        """Share of recorded episodes whose status is ``error`` (0 when none is recorded)."""
        return len(self.errors) / self.recorded if self.recorded else 0.0

    def error_kinds(self) -> dict[str, tuple[int, str]]:
        """Errors grouped by kind (the text before the first colon): count and first text."""
        kinds: dict[str, tuple[int, str]] = {}
        for text in self.errors.values():
            kind = text.split(":", 1)[0][:80] or "error"
            count, first = kinds.get(kind, (0, text))
            kinds[kind] = (count + 1, first)
        return kinds

    def to_json(self) -> dict[str, object]:
        return {
            "system": self.system,
            "finished": self.finished,
            "expected": len(self.expected),
            "ran_now": self.ran_now,
            "already_done": self.already_done,
            "statuses": dict(sorted(self.statuses.items())),
            "errors": {f"{s}/{e}": msg for (s, e), msg in self.errors.items()},
            "missing": [f"{s}/{e}" for s, e in self.missing],
            "wall_s": round(self.wall_s, 3),
            "runs_in_pass": self.runs_in_pass,
            "simulated_s": round(self.simulated_s, 3),
            "flights": self.flights,
            "structured_output": self.structured_output,
            "server_defaults": self.server_defaults,
            "stopped": self.stopped,
            "notes": self.notes,
        } | ({} if self.data_dir is None else {RELATIVE_DATA_KEY: self.data_dir})


def structured_levels(results: Iterable[EpisodeResult]) -> dict[str, str]:
    """Per model, the structured-output levels its answered calls used (negotiated with the
    server, or pinned), e.g. ``{"openai:gemma-3-270m": "json_object_schema"}``."""
    return _per_model(
        results, lambda call: () if call.structured_output is None else (call.structured_output,)
    )


def unsent_parameters(results: Iterable[EpisodeResult]) -> dict[str, str]:
    """Per model whose server refused some decoding parameters, those its answered calls
    went without (it decoded at its own defaults), e.g. ``{"openai:o3": "temperature"}``."""
    return _per_model(results, lambda call: call.server_defaults)


def _per_model(
    results: Iterable[EpisodeResult], values: Callable[[LlmCall], Iterable[str]]
) -> dict[str, str]:
    """Per model (``backend:model``), the values its answered calls had, listed once."""
    found: dict[str, set[str]] = {}
    for result in results:
        for call in result.llm_calls:
            if call.answered:  # a refused or failed request's settings were not answered
                for value in values(call):
                    found.setdefault(f"{call.backend}:{call.model}", set()).add(value)
    return {model: ", ".join(sorted(names)) for model, names in sorted(found.items())}


def error_verdict(reports: Sequence[RunReport], fail_on_error: float) -> str | None:
    """Why the runs fail (``None`` if they pass): a share of ``error`` episodes above
    ``fail_on_error`` (a fraction; 0 means any error fails, as inspect_ai's default), or a
    run stopped early. Says how many and why (the first error text of each kind)."""
    lines = []
    for report in reports:
        rerun = f"skyvln-eval run {report.run_dir / CONFIG_FILE} --out {report.run_dir}"
        if report.stopped:
            lines.append(f"{report.system}: the run stopped early: {report.stopped}")
            lines.append(
                f"  {len(report.missing)} of {len(report.expected)} selected episode(s) have "
                "no result (the one that stopped the run among them); once the cause is "
                f"fixed, the same command runs them: {rerun}"
            )
        if report.errors and report.error_share > fail_on_error:
            lines.append(
                f"{report.system}: {len(report.errors)} of {report.recorded} episode(s) ended "
                f"in error ({100 * report.error_share:.1f}%, more than the allowed "
                f"{100 * fail_on_error:g}%; --fail-on-error sets it)"
            )
            for count, first in report.error_kinds().values():
                lines.append(f"  {count} x {first}")  # the first text starts with its kind
            # A resume leaves error rows be; a crash of the machine is not the agent's result.
            which = "the others" if report.stopped else "them"
            lines.append(
                f"  to run {which} again (e.g. after a worker crash or an endpoint outage): "
                f"{rerun} --retry-failed"
            )
    return "\n".join(lines) or None


class Progress:
    """Receives run events; the CLI shows a progress bar, tests collect them."""

    def start(self, description: str, total: int, already_done: int) -> None: ...

    def episode_done(self, result: EpisodeResult, success: bool | None) -> None:
        """``success`` is ``None`` for an episode that cannot be scored (no ground truth)."""

    def finish(self, reports: Sequence[RunReport]) -> None: ...


def _success(result: EpisodeResult) -> bool | None:
    """Whether the episode reached its goal, as its scores will say under the default
    conventions (an error or a crash never succeeds); ``None`` when its ground truth is
    withheld."""
    if not result.has_ground_truth:
        return None
    flew, crashed = len(result.visited_views) > 0, touched_an_obstacle(result)
    if not can_succeed([result.status], [flew], [crashed])[0]:
        return False
    return view_success(result.visited_views[-1], result.gt_path_corners[-1])


def _crash_result(config: RunConfig, task: EpisodeTask, error: BaseException) -> EpisodeResult:
    # The worker died (or Ray lost it) before returning a row: record the episode as failed.
    message = f"worker crashed: {type(error).__name__}: {error}"
    return failed_result(config, task, read_episode(task.episode_log), message)


@dataclass
class RunJob:
    """One run prepared for execution: its store, its report and the episodes still to run."""

    config: RunConfig
    run_dir: Path
    store: ResultStore
    report: RunReport
    tasks: list[EpisodeTask]
    lock: RunDirLock | None = None  # held from preparation to the last recorded row

    def release(self) -> None:
        if self.lock is not None:
            self.lock.release()


def speed_cap_note(config: RunConfig) -> str | None:
    """A note when the controller cannot fly as fast as the reference asks (a PID's speed
    cap below the cruise speed): its tracking error and flight times then measure the cap,
    not the controller, which a comparison of controllers must know."""
    if config.mode != "dynamics":
        return None
    dynamics = config.dynamics
    settings = controller_config(dynamics.controller, dynamics.controller_settings)
    cap = getattr(settings, "max_speed_m_s", None)
    if cap is None or cap >= dynamics.cruise_speed_m_s:
        return None
    return (
        f"{dynamics.controller}'s max_speed_m_s {cap:g} is below the cruise speed "
        f"{dynamics.cruise_speed_m_s:g} m/s: it lags the reference, so its tracking errors "
        "and flight times measure the cap, and so do its collisions and clearance (the "
        "obstacles cross the reference's path when the reference passes, long before a "
        "lagging drone does; an audit's PID crashed at 15 m/s and not at 5). Raise it in "
        "controller_settings for a like-for-like comparison"
    )


def prepare_job(config: RunConfig, run_dir: str | Path, retry_failed: bool = False) -> RunJob:
    """Convert the run's episodes if needed, check the run directory, find what is left."""
    run_dir = Path(run_dir)
    data_dir = resolve_data_dir(config.data)
    check_same_data(config, data_dir, run_dir)  # before any work on the wrong data
    logs = episode_logs(config, data_dir)
    preflight(config, data_dir, (episode_id.rsplit("__", 1)[0] for _, episode_id in logs))
    # Locked before anything in it is read: a second launch refuses instead of running
    # the same episodes (the lock dies with this process, however it ends).
    lock = hold_run_dir(run_dir)
    try:
        prepare_run_dir(config, run_dir)
        leftovers = remove_leftover_temporaries(run_dir, RUN_FILES, RUN_FOLDERS)
        store = ResultStore(run_dir)
        check_own_rows(config, store.results(), run_dir / RESULTS_FILE)
        # In the run directory, which exists now: a relative cache_path is placed there.
        said_of_caches = cache_notes(config.agent, run_dir, f"run {config.system!r}")
    except BaseException:
        lock.release()
        raise
    notes = store.recovery.messages() + said_of_caches
    if leftovers:
        notes.append(f"removed {leftovers} temporary file(s) left by an interrupted run")
    cap = speed_cap_note(config)
    notes += [cap] if cap else []
    relative = str(data_dir) if is_relative_data(config.data) else None
    report = RunReport(run_dir, config.system, list(logs), notes=notes, data_dir=relative)
    todo = store.missing(logs, retry_failed=retry_failed)
    pending = set(todo)
    lost = lost_files(config, run_dir, store, [key for key in logs if key not in pending])
    if lost:  # run again: the same row (runs are deterministic), its files written anew
        again = pending | set(lost)
        todo = [key for key in logs if key in again]
        first = next(iter(lost.values()))
        notes.append(
            f"{len(lost)} recorded episode(s) run again: a file of theirs was missing or "
            f"damaged (e.g. {first})"
        )
    report.already_done = len(logs) - len(todo)
    if todo:  # a launch that makes rows: the code that makes them is recorded
        record_launch(run_dir / VERSIONS_FILE, len(store.results()))
    mixed = mixed_versions_note(run_dir / VERSIONS_FILE)
    notes += [mixed] if mixed else []
    # Said before any episode runs: a launch stopped on the way leaves this run.json, not
    # the last finished launch's (which may have selected fewer episodes).
    report.missing = list(todo)
    atomic_write_json(run_dir / REPORT_FILE, report.to_json(), indent=1)
    config_json = config.model_dump_json()
    tasks = [
        EpisodeTask(
            config_json,
            str(data_dir),
            str(run_dir),
            split,
            episode_id,
            str(logs[(split, episode_id)]),
            # Run again after an error: its answers come from the endpoint, not the cache.
            fresh_answers=retry_failed and _recorded_error(store, (split, episode_id)),
        )
        for split, episode_id in todo
    ]
    return RunJob(config, run_dir, store, report, tasks, lock)


def _recorded_error(store: ResultStore, key: RowKey) -> bool:
    row = store.get(key)
    return row is not None and row.status == "error"


def _finish(job: RunJob, wall_s: float, runs_in_pass: int = 1, finished: bool = True) -> None:
    """The job's report from its rows, written to ``run.json``; ``wall_s`` is the pass's
    (shared by its ``runs_in_pass`` runs, whose episodes ran interleaved)."""
    report = job.report
    report.wall_s = wall_s
    report.runs_in_pass = runs_in_pass
    # A row that stopped the run (refused credentials, a full disk) says nothing of its
    # episode, which the next launch runs again: it has no result yet, and is no error.
    results = {key_of(r): r for r in job.store.results() if not r.stopped_the_run}
    report.missing = [key for key in report.expected if key not in results]
    report.statuses = {}
    for key in report.expected:
        if key in results:
            status = results[key].status
            report.statuses[status] = report.statuses.get(status, 0) + 1
    flown_rows = [results[k] for k in report.expected if k in results and results[k].control]
    flown = [r.control for r in flown_rows if r.control is not None]
    if flown:
        report.flights = {
            "flown": len(flown),
            "crashed": sum(c.collided for c in flown),
            "with failed solves": sum(c.solve_failures > 0 for c in flown),
            "with segments cut short": sum((r.segments_cut_short or 0) > 0 for r in flown_rows),
        }
    report.errors = {
        key: (results[key].error or "error").splitlines()[0]
        for key in report.expected
        if key in results and results[key].status == "error"
    }
    withheld = [k for k in report.expected if k in results and not results[k].has_ground_truth]
    if withheld:
        splits = ", ".join(sorted({split for split, _ in withheld}))
        report.notes.append(
            f"{len(withheld)} episode(s) of {splits} have no ground truth (withheld, as in the "
            "real AVDN test_unseen): their routes are recorded but cannot be scored"
        )
    report.structured_output = structured_levels(results.values())
    report.server_defaults = unsent_parameters(results.values())
    report.finished = finished
    atomic_write_json(job.run_dir / REPORT_FILE, report.to_json(), indent=1)


def execute_jobs(
    jobs: Sequence[RunJob],
    executor: Executor,
    progress: Progress | None = None,
    description: str = "episodes",
    task_function: Callable[[EpisodeTask], EpisodeResult] = run_episode_task,
) -> list[RunReport]:
    """Run every job's remaining episodes in one executor pass; rows go to each job's store.

    Tasks are grouped by map (then run, then episode) so that each worker's world cache
    serves many episodes in a row. Each job's run directory lock is released at the end,
    however it ends.
    """
    try:
        return _execute_jobs(jobs, executor, progress, description, task_function)
    finally:
        for job in jobs:
            job.release()


def _execute_jobs(
    jobs: Sequence[RunJob],
    executor: Executor,
    progress: Progress | None,
    description: str,
    task_function: Callable[[EpisodeTask], EpisodeResult],
) -> list[RunReport]:
    progress = progress or Progress()
    by_dir = {str(job.run_dir): job for job in jobs}
    tasks = sorted(
        (task for job in jobs for task in job.tasks),
        key=lambda t: (t.episode_id.split("__")[0], t.run_dir, t.split, t.episode_id),
    )
    total = sum(len(job.report.expected) for job in jobs)
    progress.start(description, total, total - len(tasks))
    started = time.perf_counter()
    try:
        for task, outcome in executor.map_unordered(task_function, tasks):
            job = by_dir[task.run_dir]
            if isinstance(outcome, NoWorkerLeft):  # it never ran: no row, a resume runs it
                why = f"{outcome}: every worker process died; the episodes left did not run"
                for unfinished in jobs:
                    if unfinished.report.ran_now < len(unfinished.tasks):
                        unfinished.report.stopped = why
                break
            result = (
                outcome
                if isinstance(outcome, EpisodeResult)
                else _crash_result(job.config, task, outcome)
            )
            job.store.append(result)
            job.report.ran_now += 1
            if job.config.mode == "dynamics":  # flown time; an official step's is nominal
                job.report.simulated_s += float(result.extra.get("simulated_s", 0.0))
            if result.stopped_the_run:  # e.g. refused credentials: no later one can succeed
                # Not an episode's result (the summary counts it as not run): the bar
                # does not count it done, nor as an error.
                job.report.stopped = str(result.extra["fatal"])
                break
            progress.episode_done(result, _success(result))
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM: each run.json says where the launch got
        for job in jobs:
            _finish(job, time.perf_counter() - started, len(jobs), finished=False)
        raise
    except ResultsWriteError:  # a full disk: run.json too says where it got, if it can
        for job in jobs:
            with contextlib.suppress(OSError):  # the disk that refused the row may refuse it
                _finish(job, time.perf_counter() - started, len(jobs), finished=False)
        raise
    wall_s = time.perf_counter() - started
    for job in jobs:
        _finish(job, wall_s, len(jobs))
    reports = [job.report for job in jobs]
    progress.finish(reports)
    return reports


def run(
    config: RunConfig,
    run_dir: str | Path,
    executor: Executor | None = None,
    progress: Progress | None = None,
    retry_failed: bool = False,
    task_function: Callable[[EpisodeTask], EpisodeResult] = run_episode_task,
) -> RunReport:
    """Run ``config`` into ``run_dir``, skipping episodes already recorded there, and say
    what happened.

    Episodes that end in ``error`` (no usable LLM answer, or the episode raised) are
    recorded and counted, not raised: check ``report.statuses``, ``report.error_share`` and
    ``report.errors`` (``skyvln-eval run`` exits 1 on them unless ``--fail-on-error``
    allows their share; :func:`error_verdict` is that check). ``report.complete`` is
    false while episodes are missing (``retry_failed=True`` runs the error episodes
    again). Before any episode runs, a :class:`~skyvln_eval.errors.ConfigError` (a
    :class:`~skyvln_eval.harness.preflight.PreflightError` among them) is raised for what
    would fail them all: a missing API key, a local model server with nothing listening, a
    detector whose sensor is off or that the data cannot feed. ``executor``: e.g.
    :func:`make_executor`'s, else the config's.
    """
    job = prepare_job(config, run_dir, retry_failed)
    executor = executor or make_executor(
        config.executor, config.workers, config.ray_address, config.threads_per_worker
    )
    return execute_jobs([job], executor, progress, config.system, task_function)[0]
