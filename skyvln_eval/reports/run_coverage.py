"""Which episodes a run directory was set to run, and whether its results cover them.

A ``results.jsonl`` beside a ``config.yaml`` is a run directory's
(:mod:`skyvln_eval.harness.run`). Its config selects the episodes the run covers: of each
of its splits, the episodes of its episode mode in file order, only those listed in
``episodes`` when it lists some, the first ``limit`` of them when it sets one, as
:func:`~skyvln_eval.harness.run.episode_logs` selects them for the run. ``score`` compares
the run's rows with that selection, so an interrupted run is never scored as a finished
one, and a limited run is not compared with its whole split.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import DEFAULT_MAX_ACTION_LEN, EpisodeMode
from skyvln_eval.errors import (
    AlteredGroundTruthError,
    ConfigError,
    DataError,
    ForeignRowsError,
    IncompleteRunError,
    SkyvlnError,
    listed,
)
from skyvln_eval.harness.config import RunConfig, run_config_from_mapping
from skyvln_eval.harness.run import (
    CONFIG_FILE,
    REPORT_FILE,
    check_own_rows,
    is_relative_data,
    is_synthetic_data,
    recorded_data_dir,
    selected,
)
from skyvln_eval.harness.store import RESULTS_FILE, RowKey
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.results_io import stopped_run_error

#: An episode's views as (K, 4, 2) [lat, lng] corners.
Views = NDArray[np.float64]


def run_dir_of(results_file: Path) -> Path | None:
    """The run directory ``results_file`` is the results of, or ``None`` for another file."""
    folder = results_file.parent
    if results_file.name != RESULTS_FILE:
        return None
    if (folder / CONFIG_FILE).is_file():
        return folder
    if (folder / REPORT_FILE).is_file():
        raise DataError(
            f"{folder} has a run report ({REPORT_FILE}) but no {CONFIG_FILE}, so which "
            f"episodes the run was to cover is unknown; put its {CONFIG_FILE} back, or pass "
            "--allow-incomplete to score the rows it has without checking"
        )
    return None


def read_run_config(run_dir: Path) -> RunConfig:
    from skyvln_eval.fileio import read_yaml_mapping

    path = run_dir / CONFIG_FILE
    return run_config_from_mapping(read_yaml_mapping(path, "run config"), str(path))


def run_data_dir(config: RunConfig, run_dir: Path) -> Path:
    """The dataset the run ran on (``sample`` / ``full``: the cached copy, never built here)."""
    data = config.data
    if is_synthetic_data(data):
        from skyvln_eval.paths import cache_root
        from skyvln_eval.worlds.sample.build import SPECS
        from skyvln_eval.worlds.sample.cache import dataset_dir_name, is_complete

        path = cache_root() / dataset_dir_name(SPECS[data])
        found = is_complete(path)
    else:
        # A relative path names the folder it named where the run was launched.
        recorded = recorded_data_dir(run_dir) if is_relative_data(data) else None
        path = recorded or Path(data).expanduser()
        found = (path / "annotations").is_dir()
    if not found:
        raise DataError(
            f"the data of run {run_dir} ({data!r}) is not at {path}, so which episodes the "
            "run was to cover is unknown; pass --data-dir with the dataset it ran on, or "
            "--allow-incomplete to score the rows it has without checking"
        )
    return path


def selected_episodes(config: RunConfig, data_dir: Path) -> list[RowKey]:
    """The episodes ``config`` runs on ``data_dir``, in run order (see the module docstring)."""
    return list(_selected_ground_truth(config, data_dir))


def _selected_ground_truth(config: RunConfig, data_dir: Path) -> dict[RowKey, Views]:
    """The episodes ``config`` runs on ``data_dir`` with their ground-truth views."""
    from skyvln_eval.avdn import load_split

    out: dict[RowKey, Views] = {}
    for split in config.splits:
        episodes = load_split(data_dir, split, check_map_images=False).episodes(config.episode_mode)
        truth = {e.episode_id: e.gt_path_corners for e in episodes}
        out |= {(split, e): truth[e] for e in selected(config, list(truth))}
    return out


def altered_ground_truth(
    results: Iterable[EpisodeResult], truth: Mapping[RowKey, Views]
) -> list[RowKey]:
    """The rows whose ground truth (the views they are scored against, kept in the row)
    is not their episode's in the dataset: a hand-edited row, or a stale one of a dataset
    since made again, would be scored silently against a goal the dataset does not have."""
    return [
        (r.split, r.episode_id)
        for r in results
        if (r.split, r.episode_id) in truth
        and not np.array_equal(r.gt_path_corners, truth[(r.split, r.episode_id)])
    ]


def altered_error(where: str, altered: Sequence[RowKey], data_dir: Path) -> AlteredGroundTruthError:
    shown = listed(["/".join(key) for key in altered], 5)
    return AlteredGroundTruthError(
        f"{where}: {len(altered)} row(s) hold another ground truth than their episode's in "
        f"{data_dir} ({shown}): rows edited by hand, or made on another version of the "
        "dataset, would be scored against a goal it does not have; run them again (or "
        "score them against the dataset they were made on, --data-dir)"
    )


@dataclass(frozen=True)
class RunCoverage:
    """How the rows of a run directory cover the episodes its config selects.

    ``stopped`` rows only record that the run stopped there (refused credentials, a full
    disk: ``extra["fatal"]``); the run runs their episodes again, so they count as missing.
    """

    run_dir: Path
    system: str
    data_dir: Path
    expected: tuple[RowKey, ...]
    missing: tuple[RowKey, ...]
    stopped: tuple[RowKey, ...]
    unexpected: tuple[RowKey, ...]

    @property
    def complete(self) -> bool:
        return not self.missing and not self.unexpected

    @property
    def recorded(self) -> int:
        return len(self.expected) - len(self.missing)

    def _what(self) -> str:
        return (
            f"run {self.run_dir} (system {self.system!r}: {len(self.expected)} episode(s) "
            f"selected by its {CONFIG_FILE}, {self.recorded} recorded)"
        )

    def _finish_it(self) -> str:
        config = self.run_dir / CONFIG_FILE
        stopped = (
            f" ({len(self.stopped)} of the missing have a row that only records the run "
            "stopping there, e.g. refused credentials)"
            if self.stopped
            else ""
        )
        return (
            f"Finish it with `skyvln-eval run {config} --out {self.run_dir}`, which runs only "
            f"the missing episodes{stopped}"
        )

    def error(self, why_missing: str = "") -> IncompleteRunError:
        """The error of an incomplete run; ``why_missing`` says why some of the missing
        have no row, e.g. only a damaged one (:meth:`RecoveryReport.why_missing`)."""
        if self.unexpected:
            hint = f"Is {self.data_dir} the dataset the run ran on? (--data-dir gives another)"
        else:
            hint = (
                f"{why_missing}{self._finish_it()}, or pass --allow-incomplete (in Python, "
                f"allow_incomplete=True) to score the {self.recorded} recorded episode(s) "
                "as they are"
            )
        return IncompleteRunError(
            self._what(),
            [f"{split}/{episode_id}" for split, episode_id in self.missing],
            [f"{split}/{episode_id}" for split, episode_id in self.unexpected],
            hint=hint,
            outside=f"the run's selection from {self.data_dir}",
        )

    def warning(self) -> str:
        """What ``--allow-incomplete`` says about the scores of an incomplete run."""
        shown = ", ".join(f"{s}/{e}" for s, e in self.missing[:5])
        more = " ..." if len(self.missing) > 5 else ""
        left_out = (
            f"; the {len(self.stopped)} row(s) that only record the run stopping are left out"
            if self.stopped
            else ""
        )
        return (
            f"INCOMPLETE: {self._what()}: {len(self.missing)} episode(s) missing ({shown}{more})"
            f"{left_out}. Its scores cover only the {self.recorded} recorded episode(s). "
            f"{self._finish_it()}."
        )


def run_coverage(
    run_dir: Path, results: Sequence[EpisodeResult], data_dir: Path | None = None
) -> RunCoverage:
    """How ``results`` (the rows of ``run_dir``) cover the episodes its config selects,
    from ``data_dir`` or, by default, the dataset the run ran on."""
    config = read_run_config(run_dir)
    check_own_rows(config, results, run_dir / RESULTS_FILE)
    data_dir = data_dir if data_dir is not None else run_data_dir(config, run_dir)
    try:
        truth = _selected_ground_truth(config, data_dir)
    except SkyvlnError as error:  # e.g. a split the dataset does not have
        raise DataError(
            f"cannot tell which episodes run {run_dir} covers from {data_dir}: {error}"
        ) from None
    expected = list(truth)
    altered = altered_ground_truth(results, truth)
    if altered:  # never scored, allowed incomplete or not
        raise altered_error(f"run {run_dir}", altered, data_dir)
    rows = {(r.split, r.episode_id): r for r in results}
    stopped = [key for key in expected if key in rows and rows[key].stopped_the_run]
    missing = [key for key in expected if key not in rows or rows[key].stopped_the_run]
    return RunCoverage(
        run_dir=run_dir,
        system=config.system,
        data_dir=data_dir,
        expected=tuple(expected),
        missing=tuple(missing),
        stopped=tuple(stopped),
        unexpected=tuple(sorted(set(rows) - set(expected))),
    )


def long_path_warnings(sources: list[tuple[str, list[EpisodeResult]]]) -> list[str]:
    """A warning per input whose paths hold more views than AVDN's ``max_action_len`` (10,
    the start included) for each dialog round they fly (a row's ``rounds_flown``; one in
    ANDH; an ANDH-Full row that does not say is not checked): OSR and oracle GP count
    every view visited, so more views make them higher than the paper's protocol allows."""
    warnings = []
    for name, rows in sources:
        long = [
            (len(r.visited_views), budget)
            for r in rows
            if (budget := _avdn_view_budget(r)) is not None and len(r.visited_views) > budget
        ]
        if long:
            budgets = sorted({budget for _, budget in long})
            warnings.append(
                f"{name}: {len(long)} episode(s) visited more views than AVDN's "
                f"max_action_len ({DEFAULT_MAX_ACTION_LEN} per dialog round, the start "
                f"counted: {', '.join(map(str, budgets))}) allows (up to "
                f"{max(n for n, _ in long)}): oracle success and oracle GP count every "
                "view, so they are not comparable with the paper's"
            )
    return warnings


def _avdn_view_budget(row: EpisodeResult) -> int | None:
    rounds = row.extra.get("rounds_flown", 1 if row.mode == "andh" else None)
    return None if rounds is None else DEFAULT_MAX_ACTION_LEN * int(rounds)


def covered_results(
    sources: list[tuple[str, list[EpisodeResult]]], data_dir: Path | None, allow_incomplete: bool
) -> tuple[list[EpisodeResult], list[str]]:
    """The rows to score and a warning per incomplete input (with ``allow_incomplete``;
    else an incomplete input raises).

    The rows of a run directory must cover the episodes its config selects (from
    ``data_dir`` if given, else from the data it ran on); other results, given
    ``data_dir``, every episode of their split. Rows of episodes outside those always raise.
    """
    rows: list[EpisodeResult] = []
    warnings: list[str] = []
    plain: dict[tuple[str, str, EpisodeMode], list[EpisodeResult]] = {}  # by system, split, mode
    for name, results in sources:
        try:
            run_dir = run_dir_of(Path(name))
            coverage = None if run_dir is None else run_coverage(run_dir, results, data_dir)
        except (ForeignRowsError, AlteredGroundTruthError):
            raise  # rows not this run's, or not its dataset's: allowed or not
        except (ConfigError, DataError) as error:  # which episodes the run covers is unknown
            if not allow_incomplete:
                raise
            warnings.append(f"NOT CHECKED whether {name} is complete: {error}")
            rows += _ran(name, results, allow_incomplete, warnings)
            continue
        if coverage is None:
            _one_configuration_per_system(name, results)
            results = _ran(name, results, allow_incomplete, warnings)
            rows += results
            for r in results:
                plain.setdefault((r.system, r.split, r.mode), []).append(r)
            if data_dir is None:  # nothing to compare them with: say so, in every table
                warnings.append(
                    f"NOT CHECKED whether {name} covers its episodes (not in a run directory, "
                    f"and no --data-dir): its scores cover the {len(results)} episode(s) it has"
                )
            continue
        if not coverage.complete:
            if coverage.unexpected or not allow_incomplete:
                raise coverage.error()
            warnings.append(coverage.warning())
        rows += [r for r in results if (r.split, r.episode_id) not in coverage.stopped]
    if data_dir is not None:
        warnings += _split_coverage(plain, data_dir, allow_incomplete)
    return rows, warnings


def _ran(
    name: str, results: list[EpisodeResult], allow_incomplete: bool, warnings: list[str]
) -> list[EpisodeResult]:
    """``results`` without the rows that only record a run stopping (``extra["fatal"]``),
    which no episode's score is: with them the file raises, unless ``allow_incomplete``
    (then ``warnings`` says they are left out)."""
    stopped = [r for r in results if r.stopped_the_run]
    if not stopped:
        return results
    if not allow_incomplete:
        raise stopped_run_error(name, stopped)
    warnings.append(
        f"INCOMPLETE: {name}: {len(stopped)} row(s) only record the run stopping there and "
        "are left out; the episodes after them never ran"
    )
    return [r for r in results if not r.stopped_the_run]


def _one_configuration_per_system(name: str, results: Sequence[EpisodeResult]) -> None:
    """Refuse results in which one system's rows were made by different settings (their
    ``settings_digest``): outside a run directory nothing else tells them apart, and a
    table would pool them in one row."""
    seen: dict[str, tuple[str, str]] = {}  # system -> (digest, first episode)
    for r in results:
        digest = r.extra.get("settings_digest")
        if not isinstance(digest, str):
            continue  # rows of older runs did not record it
        first = seen.setdefault(r.system, (digest, f"{r.split}/{r.episode_id}"))
        if first[0] != digest:
            raise ForeignRowsError(
                f"{name}: system {r.system!r} has rows made by different settings "
                f"({first[1]}: {first[0]}; {r.split}/{r.episode_id}: {digest}), which a table "
                "would pool in one row; give the runs different system labels"
            )


def _split_coverage(
    plain: dict[tuple[str, str, EpisodeMode], list[EpisodeResult]],
    data_dir: Path,
    allow_incomplete: bool,
) -> list[str]:
    """A warning per (system, split, mode) of ``plain`` (its rows) that lacks some
    episodes of its split in ``data_dir`` (with ``allow_incomplete``, else it raises);
    rows whose ground truth is not their episode's there always raise."""
    from skyvln_eval.metrics import check_complete, ground_truth_episodes

    warnings = []
    for (system, split, mode), results in sorted(plain.items()):
        ids = [r.episode_id for r in results]
        episodes = ground_truth_episodes(data_dir, split, mode)
        truth = {(split, e.episode_id): e.gt_path_corners for e in episodes}
        altered = altered_ground_truth(results, truth)
        if altered:
            raise altered_error(f"run {system}/{split}/{mode}", altered, data_dir)
        try:
            check_complete(ids, [e.episode_id for e in episodes], f"run {system}/{split}/{mode}")
        except IncompleteRunError as error:
            if error.unexpected or not allow_incomplete:
                raise
            warnings.append(
                f"INCOMPLETE: {error}. Its scores cover only the {len(ids)} episode(s) it has."
            )
    return warnings
