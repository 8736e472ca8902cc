"""Reading a run's results in Python: :func:`run_results`, checked as ``score`` checks them.

A run directory (``skyvln-eval run --out DIR``) holds ``config.yaml`` and
``results.jsonl``. ``reproduce`` writes one run directory per system and split
(``runs/<system>/<split>``); the folder of a system's split runs is read as all of them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from skyvln_eval.errors import (
    AlteredGroundTruthError,
    ConfigError,
    DataError,
    ForeignRowsError,
    IncompleteRunError,
    listed,
)
from skyvln_eval.harness.run import CONFIG_FILE
from skyvln_eval.harness.store import (
    RESULTS_FILE,
    RecoveryReport,
    ResultStore,
    RowKey,
    key_of,
)
from skyvln_eval.metrics.records import EpisodeResult

if TYPE_CHECKING:
    from skyvln_eval.reports.run_coverage import RunCoverage


def run_results(
    run_dir: str | Path,
    keys: Sequence[RowKey | tuple[str, str, str, str]] | None = None,
    *,
    allow_incomplete: bool = False,
) -> list[EpisodeResult]:
    """The results of a run directory: all of them, or the ``(split, episode_id)``
    ``keys`` in that order (or the :attr:`EpisodeResult.key` of each).

    All of them must cover every episode the run's config selects, as ``skyvln-eval score``
    checks: a run still going, or stopped, raises :class:`IncompleteRunError` naming the
    missing episodes, so that half a run is not summarised as a run. A key without a row
    raises too, naming it. ``allow_incomplete`` returns the rows recorded so far (of
    ``keys``, those recorded). A row that only records the run stopping (refused
    credentials, a full disk) is never returned: it is no episode's result.

    Whatever is asked, and allowed incomplete or not, the run's rows are checked as
    ``score`` checks them: rows another config made (:class:`ForeignRowsError`), rows whose
    ground truth is not their episode's in the dataset (:class:`AlteredGroundTruthError`)
    and rows of episodes its config does not select raise. A run whose episodes cannot be
    known (no ``config.yaml``, its data moved) raises, or with ``allow_incomplete`` warns
    that its rows are not checked.

    ``run_dir`` may also be a folder of run directories, as ``reproduce`` writes a
    system's splits (``runs/full/val_seen``, ...): each is read and checked as above, and
    their rows returned together, in the folders' name order.
    """
    folder = Path(run_dir)
    runs = run_directories(folder)
    if keys is None:
        return [r for one in runs for r in _all_rows(one, allow_incomplete)]
    rows: dict[RowKey, EpisodeResult] = {}
    recoveries: list[RecoveryReport] = []
    for one in runs:
        store = _opened(one)
        recoveries.append(store.recovery)
        results = store.results()
        # Checked as a whole run is, its completeness aside: a row edited by hand or made
        # by another config was returned for its key as if it were this run's.
        _checked_coverage(one, results, allow_incomplete)
        for row in results:
            key = key_of(row)
            if key in rows:  # e.g. two systems' runs in one folder
                raise DataError(
                    f"{folder}: episode {'/'.join(key)} has rows in more than one of its run "
                    "directories; ask one run directory for keys"
                )
            rows[key] = row
    asked = [_row_key(folder, key) for key in keys]
    for given in keys:
        _check_system_and_mode(folder, given, rows)
    return _rows_of(folder, rows, asked, allow_incomplete, recoveries)


def _row_key(folder: Path, key: Sequence[str]) -> RowKey:
    """A key as ``(split, episode_id)``; :attr:`EpisodeResult.key`'s ``(system, split,
    mode, episode_id)`` is taken too, its system and mode the run's
    (:func:`_check_system_and_mode`)."""
    if isinstance(key, str) or len(key) not in (2, 4):
        raise DataError(
            f"{folder}: a key is (split, episode_id) or an EpisodeResult.key "
            f"(system, split, mode, episode_id), got {key!r}"
        )
    return (key[0], key[1]) if len(key) == 2 else (key[1], key[3])


def _check_system_and_mode(
    folder: Path, key: Sequence[str], rows: dict[RowKey, EpisodeResult]
) -> None:
    """Refuse an :attr:`EpisodeResult.key` of another system or episode mode than the
    run's: it is another run's episode, and the run's own row was returned for it."""
    if len(key) != 4:
        return
    system, split, mode, episode_id = key
    row = rows.get((split, episode_id))
    # An episode without a row is checked against the run's other rows.
    runs = {(r.system, r.mode) for r in ([row] if row is not None else rows.values())}
    if not runs or (system, mode) in runs:
        return
    theirs = "; ".join(f"system {s!r}, mode {m!r}" for s, m in sorted(runs))
    raise DataError(
        f"{folder}: key {tuple(key)!r} is of system {system!r}, mode {mode!r}, but the "
        f"run's rows are of {theirs}; ask for (split, episode_id), or for this run's "
        "EpisodeResult.key"
    )


def is_run_directory(folder: Path) -> bool:
    """A run's folder: the ``config.yaml`` a run writes first, or its ``results.jsonl``."""
    return (folder / CONFIG_FILE).is_file() or (folder / RESULTS_FILE).is_file()


def run_directories(folder: Path) -> list[Path]:
    """``folder`` if it is a run directory, else the run directories in it (as
    ``reproduce`` writes a system's splits); refuses what is neither, saying what it is.
    What :func:`run_results` and ``skyvln-eval view`` accept as a run."""
    if folder.is_file():
        hint = f"; pass its folder {folder.parent}" if folder.name == RESULTS_FILE else ""
        raise DataError(f"{folder}: a file, not a run directory{hint}")
    if not folder.is_dir():
        raise DataError(f"{folder}: no such run directory")
    if (folder / CONFIG_FILE).is_file() or (folder / RESULTS_FILE).exists():
        return [folder]
    runs = sorted(d for d in folder.iterdir() if is_run_directory(d))
    if runs:
        return runs
    deeper = sorted(d.name for d in folder.iterdir() if d.is_dir() and _run_dirs_in(d))
    where = f"; its folders {listed(deeper)} hold run directories" if deeper else ""
    raise DataError(
        f"{folder}: not a run directory (no {CONFIG_FILE} or {RESULTS_FILE}) nor a folder "
        f"of run directories (as reproduce's runs/<system>){where}"
    )


def _run_dirs_in(folder: Path) -> bool:
    return any((d / CONFIG_FILE).is_file() for d in folder.iterdir() if d.is_dir())


def _opened(run_dir: Path) -> ResultStore:
    """The run's store, read only (the run's own process repairs it); its damaged lines
    are told, with what becomes of their episodes: read past in silence, an episode whose
    only row was damaged looked never run, or, with ``allow_incomplete``, was left out."""
    store = ResultStore(run_dir, repair=False)
    damaged = store.recovery.damaged
    if damaged:
        shown = "; ".join(f"line {row.line}: {row.reason}" for row in damaged[:5])
        more = f"; and {len(damaged) - 5} more" if len(damaged) > 5 else ""
        warnings.warn(
            f"{store.path}: {len(damaged)} damaged line(s) read past ({shown}{more}); an "
            "episode no other row holds counts as not run (`skyvln-eval run` on the run "
            "directory sets the lines aside and runs those episodes again)",
            UserWarning,
            stacklevel=3,
        )
    return store


def _all_rows(run_dir: Path, allow_incomplete: bool) -> list[EpisodeResult]:
    store = _opened(run_dir)
    results = store.results()
    coverage = _checked_coverage(run_dir, results, allow_incomplete)
    if coverage is not None and not coverage.complete and not allow_incomplete:
        raise coverage.error(store.recovery.why_missing(coverage.missing))
    return [r for r in results if not r.stopped_the_run]


def _checked_coverage(
    run_dir: Path, results: Sequence[EpisodeResult], allow_incomplete: bool
) -> RunCoverage | None:
    """How ``results`` cover the run's episodes, as ``score`` checks them whether or not
    incomplete runs are allowed: rows another config made, rows whose ground truth is not
    their episode's and rows outside the run's selection always raise. When which episodes
    the run covers is unknown (no config, its data moved), that raises too, unless
    ``allow_incomplete`` (then a warning says the rows are not checked, and ``None``)."""
    from skyvln_eval.reports.run_coverage import run_coverage  # it reads harness.run

    try:
        coverage = run_coverage(run_dir, results)
    except (ForeignRowsError, AlteredGroundTruthError):
        raise  # allowed incomplete or not, as `score`
    except (ConfigError, DataError) as error:
        if not allow_incomplete:
            raise
        warnings.warn(
            f"NOT CHECKED whether run {run_dir} is complete and its rows its own: {error}",
            UserWarning,
            stacklevel=3,
        )
        return None
    if coverage.unexpected:
        raise coverage.error()
    return coverage


def _rows_of(
    folder: Path,
    rows: dict[RowKey, EpisodeResult],
    keys: Sequence[RowKey],
    allow_incomplete: bool,
    recoveries: Sequence[RecoveryReport],
) -> list[EpisodeResult]:
    """The rows of ``keys``; one without a row (or with one that only records the run
    stopping) raises, naming them and the damaged lines that may be theirs
    (``recoveries``: what reading each run directory found), unless ``allow_incomplete``
    leaves it out."""
    found = {k: r for k, r in rows.items() if not r.stopped_the_run}
    missing = ["/".join(key) for key in keys if key not in found]
    if missing and not allow_incomplete:
        damaged = "".join(r.why_missing(k for k in keys if k not in found) for r in recoveries)
        stopped = [k for k in keys if k in rows and k not in found]
        why = (
            f" ({len(stopped)} of them have a row that only records the run stopping there)"
            if stopped
            else ""
        )
        raise IncompleteRunError(
            f"run {folder} (asked for {len(keys)} episode(s))",
            missing,
            hint=f"Those have no usable result row{why}. {damaged}Keys are (split, episode_id); "
            f"it has rows of {len(found)} episode(s), e.g. "
            + listed(sorted("/".join(key_of(r)) for r in found.values()), 3)
            + ". Pass allow_incomplete=True to get the rows it has",
        )
    return [found[key] for key in keys if key in found]
