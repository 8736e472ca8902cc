"""Checking a run directory as ``skyvln-eval validate`` does: its result rows, the files
each recorded episode keeps, and whether it covers the episodes its config selects.

The run MCAP logs themselves are checked byte by byte by the MCAP validator (their folder
``logs/<split>/`` is a folder of logs); here a recorded episode whose log is missing is
found, and its control log (dynamics mode) is read and checked, as ``score`` reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from skyvln_eval.errors import AlteredGroundTruthError, ForeignRowsError, SkyvlnError
from skyvln_eval.harness.lock import leftover_temporaries
from skyvln_eval.harness.run import (
    CONFIG_FILE,
    RUN_FILES,
    RUN_FOLDERS,
    episode_files,
    file_damage,
    log_path,
    read_run_report,
)
from skyvln_eval.harness.run_reading import is_run_directory
from skyvln_eval.harness.store import RESULTS_FILE, ResultStore


def run_directories_at(path: Path) -> list[Path]:
    """``path`` if it is a run directory, else the run directories below it (a
    reproduction's ``runs/``, or its whole output), in name order; none for a dataset."""
    if is_run_directory(path):
        return [path]
    if not path.is_dir() or (path / "annotations").is_dir():
        return []
    found = {p.parent for name in (CONFIG_FILE, RESULTS_FILE) for p in path.rglob(name)}
    return sorted(run_dir for run_dir in found if is_run_directory(run_dir))


@dataclass
class RunCheck:
    """What checking one run directory found: ``problems`` (damage), ``notes`` (its state:
    an unfinished run is not damaged), and how many rows it has."""

    run_dir: Path
    rows: int = 0
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def check_run_directory(run_dir: Path) -> RunCheck:
    """Every row of ``results.jsonl`` parses (a damaged line is a problem naming its
    line), its rows are the run config's, each recorded episode that ended keeps its run
    MCAP and a control log that reads, and the rows cover the selected episodes (a note
    when they do not: a run still going, or stopped)."""
    from skyvln_eval.metrics.safety import read_control_log
    from skyvln_eval.reports.run_coverage import read_run_config, run_coverage

    check = RunCheck(run_dir)
    try:
        store = ResultStore(run_dir, repair=False)  # read only: a run may hold its lock
        config = read_run_config(run_dir)
    except SkyvlnError as error:
        check.problems.append(str(error))
        return check
    results = store.results()
    check.rows = len(results)
    results_file = run_dir / RESULTS_FILE
    try:  # rewritten by every launch, but its record of the data is read
        read_run_report(run_dir)
    except SkyvlnError as error:
        check.problems.append(str(error))
    for row in store.recovery.damaged:
        check.problems.append(f"{results_file} line {row.line}: damaged row ({row.reason})")
    superseded = store.recovery.superseded
    if superseded:  # score refuses such a file: which row would count is not its to guess
        split, episode_id = superseded[0]
        check.problems.append(
            f"{results_file}: {len(superseded)} episode row(s) repeated (e.g. "
            f"{split}/{episode_id}); `score` refuses the file, and resuming the run (the same "
            "command) keeps each episode's latest row"
        )
    leftovers = leftover_temporaries(run_dir, RUN_FILES, RUN_FOLDERS)
    if leftovers:  # a state, not damage: what a killed writer left, never renamed into place
        check.notes.append(
            f"{len(leftovers)} temporary file(s) of writers stopped before they finished, "
            f"e.g. {leftovers[0].relative_to(run_dir)} (the next run or resume removes them)"
        )
    for result in results:
        episode = f"episode {result.split}/{result.episode_id}"
        if result.status == "error" or result.stopped_the_run:
            # An episode that raised keeps no files (its row's are removed as it is made).
            stray = log_path(run_dir, result.split, result.episode_id)
            if stray.is_file():
                check.problems.append(
                    f"{stray}: a run log of {episode}, whose row says it ended in error (a "
                    "worker that died after writing it): the viewer would show it as it "
                    "was written; resuming with --retry-failed runs the episode again"
                )
            continue
        for path in episode_files(config, run_dir, result):
            if path.suffix == ".mcap":  # its bytes are the MCAP validator's to check
                if not path.is_file():
                    check.problems.append(f"{path}: missing (the run log of {episode})")
                continue
            damage = file_damage(path)
            if damage is not None:
                check.problems.append(f"{path}: {damage} (the control log of {episode})")
                continue
            try:
                read_control_log(path)
            except SkyvlnError as error:
                check.problems.append(f"{error} (the control log of {episode})")
    try:
        coverage = run_coverage(run_dir, results)
    except (ForeignRowsError, AlteredGroundTruthError) as error:  # not this run's rows
        check.problems.append(str(error))
        return check
    except SkyvlnError as error:  # the dataset is not on this machine: not the run's fault
        check.notes.append(f"coverage not checked: {error}")
        return check
    if coverage.missing:
        check.notes.append(
            f"{len(coverage.missing)} of its {len(coverage.expected)} episode(s) have no "
            "result row yet (a run still going, or stopped)"
        )
    if coverage.unexpected:
        check.problems.append(
            f"{len(coverage.unexpected)} row(s) of episodes its config does not select, e.g. "
            + "/".join(coverage.unexpected[0])
        )
    return check
