"""The ``convert`` command and the MCAP part of ``validate``, called from skyvln_eval.cli.

They print plain lines (one problem per line on stderr) and return the number of problems;
the CLI turns that into the exit status.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from skyvln_eval.avdn import EpisodeMode
from skyvln_eval.converters.batch import convert_split
from skyvln_eval.converters.convert import ConvertOptions
from skyvln_eval.converters.left_out import LEFT_OUT_NAME
from skyvln_eval.converters.manifest import MANIFEST_NAME
from skyvln_eval.converters.validate import (
    check_log,
    check_manifest_folder,
    folder_left_out,
    is_run_logs_folder,
    mcap_targets,
)

Echo = Callable[[str], None]


def is_mcap_target(path: Path) -> bool:
    """An MCAP file, or a folder of converted logs (a manifest or .mcap files at or below it)."""
    if path.suffix == ".mcap" or path.is_file():
        # A missing .mcap path is reported as a missing MCAP file, not as a dataset.
        return path.suffix == ".mcap"
    if not path.is_dir() or (path / "annotations").is_dir():
        return False
    return any(path.rglob("*.mcap")) or any(path.rglob(MANIFEST_NAME))


def run_convert(
    data_dir: Path,
    split: str,
    out: Path,
    mode: EpisodeMode,
    workers: int,
    options: ConvertOptions,
    skip_invalid: bool,
    echo: Echo,
    problem: Echo,
    on_progress: Callable[[int], None] | None = None,
) -> int:
    """Convert one split; report skipped records, failures and stale files. Returns failures."""
    report = convert_split(
        data_dir, split, out, mode, workers, options, skip_invalid, on_progress=on_progress
    )
    for record in report.skipped_records:
        problem(f"skipped: {record}")  # one line per record, with all its problems
    for issue in report.incomplete:
        problem(f"skipped: {issue}")
    for outcome in report.failed:
        problem(f"failed: {outcome.episode_id}: {outcome.note}")
    for removed in report.removed_stale:
        problem(f"removed {report.out_dir / removed.file_name}: {removed.reason}")
    if report.undefined_fields_note is not None:
        problem(f"note: {report.undefined_fields_note}")
    for name in report.foreign_files:
        problem(
            f"left in place {report.out_dir / name}: not a log a conversion writes (validate "
            "reports it as not listed in the manifest: keep such files elsewhere)"
        )
    size_mb = sum(r.size_bytes for r in report.rows) / 1e6
    echo(
        f"{split} ({mode}): {report.count('converted')} converted, "
        f"{report.count('skipped')} already converted (skipped), {len(report.failed)} failed, "
        f"{len(report.skipped_records)} invalid record(s) left out"
        + (f", {len(report.incomplete)} incomplete trajectory(ies)" if report.incomplete else "")
        + f"; {size_mb:.1f} MB in {report.out_dir}"
    )
    echo(f"manifest: {report.manifest_path}")
    if report.left_out():
        echo(f"left out, and why: {report.left_out_path}")
    return len(report.failed)


def run_validate_mcap(path: Path, echo: Echo, problem: Echo) -> int:
    """Check MCAP files / converted folders / a run's logs; print each problem; return how
    many. The summary counts the problems in the files and in the folders (manifests)."""
    folders, files = mcap_targets(path)
    folder_problems = bad_folders = left_out = 0
    for folder in folders:
        entries, left_out_issues = folder_left_out(folder)
        issues = check_manifest_folder(folder) + left_out_issues
        for issue in issues:
            problem(str(issue))
        # Not a problem of the folder (the conversion chose to leave them out), but told:
        # the logs are not the whole split.
        for entry in entries:
            echo(f"{folder}: left out at conversion: {entry}")
        left_out += len(entries)
        folder_problems += len(issues)
        bad_folders += bool(issues)
        files.extend(sorted(folder.glob("*.mcap")))
    file_problems = bad_files = messages = 0
    for check in map(check_log, files):
        for issue in check.issues:
            problem(str(issue))
        file_problems += len(check.issues)
        bad_files += bool(check.issues)
        messages += check.messages
    where = [
        f"{file_problems} in {bad_files} file(s)" if file_problems else "",
        f"{folder_problems} in {bad_folders} folder(s)" if folder_problems else "",
    ]
    total = file_problems + folder_problems
    status = f"{total} problem(s): {', '.join(w for w in where if w)}" if total else "ok"
    runs = sum(is_run_logs_folder(folder) for folder in folders)
    kind = f" ({runs} folder(s) of a run's logs)" if runs else ""
    told = f"; {left_out} left out at conversion ({LEFT_OUT_NAME})" if left_out else ""
    echo(f"{path}: {len(files)} MCAP file(s){kind}, {messages} message(s) checked, {status}{told}")
    return total
