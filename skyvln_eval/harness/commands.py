"""The ``run`` and ``reproduce`` commands (the CLI registers them; the work is here)."""

from __future__ import annotations

from pathlib import Path

import typer

from skyvln_eval.harness.config import DynamicsSettings, load_run_config
from skyvln_eval.harness.executors import make_executor
from skyvln_eval.harness.preflight import check_keys
from skyvln_eval.harness.progress import RichRunProgress
from skyvln_eval.harness.run import RunReport, run


def describe_report(report: RunReport) -> list[str]:
    """Human-readable lines of a completeness report (notes, failures, missing episodes)."""
    lines = [*report.notes]
    statuses = ", ".join(f"{n} {status}" for status, n in sorted(report.statuses.items()))
    splits = "/".join(dict.fromkeys(split for split, _ in report.expected))
    if report.runs_in_pass > 1:  # run interleaved with others: no wall time of its own
        timing = f" (with the pass's {report.runs_in_pass} runs, in {report.wall_s:.1f} s)"
    else:
        timing = f" in {report.wall_s:.1f} s" + (
            f" ({report.simulated_s / report.wall_s:.0f}x real time)"
            if report.wall_s and report.simulated_s  # flown in dynamics mode, run now
            else ""
        )
    lines.append(
        f"{report.system} ({splits or 'no episode'}): {len(report.expected)} episode(s) "
        f"({statuses or 'none recorded'}), {report.already_done} already done, "
        f"{report.ran_now} run now{timing}"
    )
    if report.flights:
        flights = report.flights
        lines.append(
            f"flown: {flights['flown']} episode(s), {flights['crashed']} crashed (a step that "
            f"touched an obstacle), {flights['with failed solves']} with failed solver steps "
            f"(fell back), {flights.get('with segments cut short', 0)} with a segment cut "
            "short at max_segment_time_s (the drone did not settle at its target in time)"
        )
    if report.structured_output:
        levels = ", ".join(f"{m}: {level}" for m, level in report.structured_output.items())
        lines.append(f"structured output: {levels}")
    if report.server_defaults:
        unsent = ", ".join(f"{m}: {names}" for m, names in report.server_defaults.items())
        lines.append(f"not sent (the model refuses them; its defaults applied): {unsent}")
    for (split, episode_id), message in report.errors.items():
        lines.append(f"error: {split}/{episode_id}: {message}")
    if report.missing:
        shown = ", ".join(f"{s}/{e}" for s, e in report.missing[:20])
        lines.append(f"missing {len(report.missing)} episode(s): {shown}")
    return lines


def run_command(
    config_path: Path,
    out: Path | None,
    workers: int | None,
    executor: str | None,
    ray_address: str | None,
    retry_failed: bool,
    threads_per_worker: int | None = None,
    progress: RichRunProgress | None = None,
) -> RunReport:
    config = load_run_config(
        config_path,
        workers=workers,
        executor=executor,
        ray_address=ray_address,
        threads_per_worker=threads_per_worker,
    )
    check_keys(config.agent, f"run config {config_path}")  # before episodes are converted
    if config.mode == "official" and config.dynamics != DynamicsSettings():
        typer.echo(
            f"warning: run config {config_path}: its dynamics settings are not used in mode "
            "official (nothing is flown); set mode: dynamics to fly them",
            err=True,
        )
    run_dir = out or Path("runs") / config_path.stem
    report = run(
        config,
        run_dir,
        executor=make_executor(
            config.executor, config.workers, config.ray_address, config.threads_per_worker
        ),
        progress=progress or RichRunProgress(),
        retry_failed=retry_failed,
    )
    for line in describe_report(report):
        typer.echo(line, err=line.startswith(("error", "missing", "dropped")))
    score = f"skyvln-eval score {run_dir}"
    if report.missing:  # score refuses an incomplete run unless told otherwise
        score += " --allow-incomplete; run this command again to finish the run"
    typer.echo(f"results: {run_dir / 'results.jsonl'}  ({score})")
    return report
