"""The ``skyvln-eval`` command: one sub-command per verb.

Commands only parse options, call the library and format its results; everything they
do is available from Python too. Errors the user can fix (``SkyvlnError``, and the
machine's ``OSError``: a full disk, a permission; and running out of memory) print as one
clear message and exit with status 2; validation problems exit with status 1.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
import typer.core
from rich import box
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from typer.core import TyperCommand

from skyvln_eval.bounds import MAX_THREADS_PER_WORKER, MAX_WORKERS
from skyvln_eval.errors import ConfigError, RunStoppedError, SkyvlnError, UnknownNameError

if TYPE_CHECKING:
    from skyvln_eval.avdn import SplitSummary
    from skyvln_eval.harness.progress import RichRunProgress

app = typer.Typer(
    name="skyvln-eval",
    help="Dataset and evaluation toolkit for aerial vision-and-language navigation (AVDN, SkyVLN).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
# Without a terminal Rich assumes 80 columns, which truncates tables in logs and CI.
console = Console(width=None if sys.stdout.isatty() else 110)
err_console = Console(stderr=True, width=None if sys.stderr.isatty() else 110)

DATASET_SIZES = ("sample", "full")
FAIL_ON_ERROR_HELP = (
    "Largest share of episodes (0-1) that may end in error (no usable LLM answer, an LLM "
    "call the endpoint never answered or refused as one it cannot serve (HTTP 404), every "
    "decision's action the fallback, or the episode raised) before the command fails; "
    "0: any error fails, 1: never"
)


def _echo_problem(text: str, colour: str = "red") -> None:
    """One problem per line on stderr: plain text (no wrapping, no markup), easy to grep."""
    typer.echo(typer.style(text, fg=colour), err=True)


@contextmanager
def _stoppable(
    progress: RichRunProgress | None = None,
    said: str = "the episodes that finished are kept{finished}; the same command runs the rest",
) -> Iterator[None]:
    """A long job that Ctrl-C or SIGTERM stops: its workers ended, what finished kept, a
    line that says so (``said``, with how many finished from ``progress``), exit code 130
    (as a shell reports an interrupted command)."""
    from skyvln_eval.interrupts import terminate_like_ctrl_c

    try:
        with terminate_like_ctrl_c():
            yield
    except KeyboardInterrupt:
        finished = (
            f" ({progress.finished} finished in this launch; run.json lists those left)"
            if progress is not None
            else ""
        )
        _echo_problem(f"interrupted: {said.format(finished=finished)}")
        sys.stdout.flush()
        sys.stderr.flush()
        # Ended here, not by returning: episodes running in threads cannot be stopped, and
        # Python's exit would wait for them (a minute and more against a remote LLM). What
        # finished is on disk, and a run killed at any point resumes (see the crash tests).
        os._exit(130)


def _progress(verb: str) -> Progress:
    """A transient progress bar on stderr: '<verb> <task description>'."""
    return Progress(
        TextColumn(f"[bold]{verb} {{task.description}}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
    )


def _build_dataset(size: str, out: Path | None, force: bool, workers: int) -> Path:
    from skyvln_eval.worlds.sample import SPECS, ensure_dataset, write_dataset

    if size not in DATASET_SIZES:
        raise typer.BadParameter(f"--size must be one of {', '.join(DATASET_SIZES)}")
    spec = SPECS[size]
    progress = _progress("generating")
    task = progress.add_task(f"{size} dataset maps", total=len(spec.map_splits()))

    def done(_: str) -> None:
        # Shown from the first map made: a dataset already there prints nothing (a bar
        # started and left empty leaves a blank line on stderr).
        if not progress.live.is_started:
            progress.start()
        progress.advance(task)

    try:
        if out is not None:  # the folder the user named, not a versioned one inside it
            return write_dataset(spec, out, workers, force, on_map_done=done)
        return ensure_dataset(spec, None, workers, force, on_map_done=done)
    finally:
        if progress.live.is_started:
            progress.stop()


@app.command()
def sample(
    size: Annotated[
        str,
        typer.Option(
            help="'sample' (a few maps and episodes) or 'full' (AVDN-sized, 6,269 records)"
        ),
    ] = "sample",
    out: Annotated[
        Path | None,
        typer.Option(
            help="Folder to write the dataset into, new or empty (default: a folder named "
            "by its version in the cache, reused by runs' data: sample)"
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option(help="Rebuild even if it exists (replacing a dataset in --out)")
    ] = False,
    workers: Annotated[int, typer.Option(min=1, help="Processes for map generation")] = 1,
) -> None:
    """Generate the synthetic AVDN-format dataset (byte-identical each time); print its folder."""
    path = _build_dataset(size, out, force, workers)
    console.print(str(path))


DATA_DIR_HELP = (
    "AVDN-format dataset folder (annotations/, train_images/), or 'sample' / 'full': the "
    "synthetic datasets, built on first use (as a run config's data:)"
)


def data_dir_argument(value: str) -> Path:
    """A ``--data-dir`` / ``DATA_DIR`` value: ``sample`` or ``full`` (the synthetic
    datasets, built on first use with a progress bar, as a run config's ``data:``), else a
    folder (``./sample`` for a folder of that name)."""
    if value in DATASET_SIZES:
        return _build_dataset(value, None, False, 1)
    return Path(value)


def _split_table(summaries: list[SplitSummary]) -> Table:
    table = Table(
        title="AVDN-format dataset",
        caption="rounds: trajectories with 1/2/3/4+ rounds",
        box=box.SIMPLE_HEAD,
    )
    for column in (
        "split",
        "records",
        "traj",
        "maps",
        "rounds",
        "views",
        "GT m",
        "D_net m",
        "edge m",
        "replay IoU",
    ):
        table.add_column(column, justify="left" if column == "split" else "right")
    for s in summaries:
        if s.ground_truth_withheld:
            replay = "withheld"
        else:
            replay = f"{s.gt_replay_min_iou:.6f}" if s.gt_replay_min_iou is not None else "-"
        rounds = (
            "/".join(str(s.rounds.get(k, 0)) for k in (1, 2, 3))
            + f"/{sum(v for k, v in s.rounds.items() if k >= 4)}"
        )
        none = s.records == 0  # every record skipped: no means to show ("nan" was shown)
        table.add_row(
            s.split,
            str(s.records),
            str(s.trajectories),
            str(s.maps),
            rounds,
            "-" if none else f"{s.mean_views:.1f}",
            "-" if none else f"{s.mean_gt_length_m:.0f}",
            "-" if none else f"{s.mean_d_net_m:.0f}",
            "-" if none else f"{s.min_edge_m:.0f}-{s.max_edge_m:.0f}",
            replay,
        )
    return table


def _summarise(data_dir: Path, skip_invalid: bool) -> list[SplitSummary]:
    from skyvln_eval.avdn import SPLITS, annotation_file_name, load_split, summarise_split
    from skyvln_eval.errors import DataError

    expected = ", ".join(f"annotations/{annotation_file_name(s)}" for s in SPLITS)
    if not data_dir.is_dir():
        what = "is a file, not" if data_dir.exists() else "does not exist; expected"
        raise DataError(
            f"{data_dir} {what} a dataset folder with {expected} (one split or more), or "
            "'sample' / 'full' for the synthetic datasets"
        )
    found = [s for s in SPLITS if (data_dir / "annotations" / annotation_file_name(s)).is_file()]
    if not found:
        raise DataError(f"{data_dir}: no annotation file of any split; expected {expected}")
    summaries = []
    for split in SPLITS:
        if split not in found:
            _echo_problem(f"{split}: no annotation file, skipped", "yellow")
            continue
        loaded = load_split(data_dir, split, skip_invalid=skip_invalid)
        for record in loaded.skipped_records:
            _echo_problem(f"skipped: {record}", "yellow")  # one line per record
        if loaded.skipped:
            _echo_problem(
                f"{split}: skipped {len(loaded.skipped_record_indices)} invalid record(s), "
                f"loaded {len(loaded.records)}",
                "yellow",
            )
        summaries.append(summarise_split(loaded))
    return summaries


@app.command()
def summary(
    data_dir: Annotated[str, typer.Argument(help=DATA_DIR_HELP, show_default=False)],
    skip_invalid: Annotated[
        bool, typer.Option(help="Skip invalid records (each is reported) instead of failing")
    ] = False,
) -> None:
    """Load every split of a dataset and print its figures.

    A folder without the annotation file of any split is an error (exit 2).
    """
    console.print(_split_table(_summarise(data_dir_argument(data_dir), skip_invalid)))


def _validate_run_directory(run_dir: Path) -> int:
    """Print what checking a run directory's rows and episode files found; the problems."""
    from skyvln_eval.harness.run_check import check_run_directory

    check = check_run_directory(run_dir)
    for problem in check.problems:
        _echo_problem(problem)
    for note in check.notes:
        typer.echo(f"{run_dir}: note: {note}")
    status = f"{len(check.problems)} problem(s)" if check.problems else "ok"
    typer.echo(f"{run_dir}: run directory, {check.rows} result row(s), {status}")
    return len(check.problems)


@app.command()
def validate(
    targets: Annotated[
        list[str],
        typer.Argument(
            help="Dataset folders (or sample / full, the synthetic datasets), MCAP files, "
            "folders of converted MCAP logs, or run directories",
            metavar="PATHS...",
        ),
    ],
    no_images: Annotated[
        bool,
        typer.Option("--no-images", help="Do not check that map images exist and decode"),
    ] = False,
) -> None:
    """Report every problem in the given datasets, MCAP logs or run directories; exit 1 if
    there is any, 2 for a path that is none of them.

    MCAP files are checked byte by byte (CRCs), message by message (JSON schema of their
    channel) and for their format version; folders of converted logs also against their
    manifest (a run directory's logs have none: only their files are checked). A run
    directory's result rows are parsed, and each recorded episode's run log must be there
    and its control log read.
    """
    from skyvln_eval.avdn import (
        SPLITS,
        annotation_file_name,
        start_heading_note,
        undefined_fields_note,
    )
    from skyvln_eval.avdn.loader import andh_full_notes, check_split_indexed
    from skyvln_eval.converters.commands import is_mcap_target, run_validate_mcap
    from skyvln_eval.harness.run_check import run_directories_at
    from skyvln_eval.worlds.checks import MapCheck

    problems = unreadable = 0
    map_check = MapCheck()  # each map decoded once, whichever splits use it
    for target in targets:
        path = data_dir_argument(target)  # "sample" as summary and convert read it
        runs = run_directories_at(path)
        for run_dir in runs:
            problems += _validate_run_directory(run_dir)
        if is_mcap_target(path):
            problems += run_validate_mcap(path, typer.echo, _echo_problem)
        if runs or is_mcap_target(path):
            continue
        found = False
        for split in SPLITS:
            if not (path / "annotations" / annotation_file_name(split)).is_file():
                continue
            found = True
            file = str(path / "annotations" / annotation_file_name(split))
            try:
                checked = check_split_indexed(path, split, not no_images)
            except SkyvlnError as exc:
                _echo_problem(str(exc))
                problems += 1
                continue
            indices, records, issues = checked.indices, checked.records, checked.issues
            map_problems: list[str] = []
            if not no_images:  # before the verdict: a record whose map misfits is no valid one
                map_issues, map_problems = map_check.check(path, file, records, indices)
                misfit = {i.record_index for i in map_issues}
                records = [r for r, i in zip(records, indices, strict=True) if i not in misfit]
                issues = sorted(issues + map_issues, key=lambda i: i.record_index or 0)
            for issue in issues:
                _echo_problem(str(issue))
            for problem in map_problems:
                _echo_problem(problem)
            problems += len(issues) + len(map_problems)
            bad = len({i.record_index for i in issues})
            verdict = [f"{len(issues)} problem(s) in {bad} record(s)"] if issues else []
            verdict += [f"{len(map_problems)} map image problem(s)"] if map_problems else []
            status = "; ".join(verdict) or "ok"
            typer.echo(f"{path} {split}: {len(records)} valid record(s), {status}")
            for note in (undefined_fields_note(records), start_heading_note(records)):
                if note is not None:
                    typer.echo(f"{path} {split}: note: {note}")
            for trajectory in andh_full_notes(checked, split, file):
                typer.echo(f"note: {trajectory}")
        if not found:
            _echo_problem(_not_validated(Path(path)))
            unreadable += 1
    if unreadable:  # a wrong argument, as other commands answer one
        raise typer.Exit(2)
    if problems:
        raise typer.Exit(1)


def _not_validated(path: Path) -> str:
    """Why ``validate`` cannot read ``path`` as a dataset, MCAP logs or a run directory."""
    if not path.exists():
        return f"{path}: no such file or directory"
    if path.is_file():
        run_dir = f"; validate its run directory, {path.parent}" if path.suffix == ".jsonl" else ""
        return (
            f"{path}: a file validate does not read (it reads datasets, MCAP logs and run "
            f"directories){run_dir}"
        )
    return (
        f"{path}: no annotations/<split>_data.json found (not a dataset), and no MCAP logs "
        "or run directory (no config.yaml or results.jsonl) in it"
    )


@app.command()
def convert(
    data_dir: Annotated[str, typer.Option(help=DATA_DIR_HELP)],
    split: Annotated[str, typer.Option(help="Split to convert, e.g. val_unseen")],
    out: Annotated[Path, typer.Option(help="Output folder (logs go to OUT/SPLIT/MODE/)")],
    mode: Annotated[str, typer.Option(help="'andh' (one per record) or 'andh-full'")] = "andh",
    workers: Annotated[int, typer.Option(min=1, help="Processes; output is identical")] = 1,
    observations: Annotated[
        bool, typer.Option(help="Write the GT observation image at each view")
    ] = True,
    skip_invalid: Annotated[
        bool, typer.Option(help="Skip invalid records (each is reported) instead of failing")
    ] = False,
) -> None:
    """Convert a split to one Foxglove-ready MCAP log per episode plus a parquet manifest.

    Re-running skips episodes already converted from the same input; exit 1 if any failed.
    """
    from skyvln_eval.avdn import EPISODE_MODES
    from skyvln_eval.converters import ConvertOptions
    from skyvln_eval.converters.commands import run_convert

    if mode not in EPISODE_MODES:
        raise typer.BadParameter(f"--mode must be one of {', '.join(EPISODE_MODES)}")
    dataset = data_dir_argument(data_dir)
    stopped = (
        "the episode logs written are kept (no partial file is left under a log's name); "
        "the same command converts the rest"
    )
    with _stoppable(said=stopped), _progress("converting") as progress:
        task = progress.add_task(split, total=None)
        failures = run_convert(
            dataset,
            split,
            out,
            mode,
            workers,
            ConvertOptions(observations=observations),
            skip_invalid,
            typer.echo,
            _echo_problem,
            on_progress=lambda n: progress.advance(task, n),
        )
    if failures:
        raise typer.Exit(1)


@app.command("run")
def run_(
    config: Annotated[
        Path, typer.Argument(help="Run config (YAML), e.g. configs/runs/full-nmpc.yaml")
    ],
    out: Annotated[
        Path | None, typer.Option(help="Run directory (default: runs/<config name>)")
    ] = None,
    # Bounded by the run config, which names the option with every other bad setting.
    workers: Annotated[
        int | None, typer.Option(min=1, help="Parallel episodes (overrides the config)")
    ] = None,
    executor: Annotated[
        str | None, typer.Option(help="serial, processes, threads or ray (overrides the config)")
    ] = None,
    ray_address: Annotated[
        str | None, typer.Option(help="Ray cluster address (default: a local Ray)")
    ] = None,
    threads_per_worker: Annotated[
        int | None,
        typer.Option(min=1, help="With processes: episodes run in threads in each worker"),
    ] = None,
    retry_failed: Annotated[
        bool, typer.Option(help="Run episodes that ended in error before again")
    ] = False,
    fail_on_error: Annotated[float, typer.Option(min=0.0, max=1.0, help=FAIL_ON_ERROR_HELP)] = 0.0,
) -> None:
    """Run an agent configuration over its episodes; resumes where a previous run stopped.

    Exits 1 when episodes are missing, the run stopped early, or more than
    --fail-on-error of its episodes ended in error.
    """
    from skyvln_eval.harness.commands import run_command
    from skyvln_eval.harness.progress import RichRunProgress
    from skyvln_eval.harness.run import error_verdict

    progress = RichRunProgress()
    with _stoppable(progress):
        report = run_command(
            config, out, workers, executor, ray_address, retry_failed, threads_per_worker,
            progress,
        )  # fmt: skip
    verdict = error_verdict([report], fail_on_error)
    if verdict:
        _echo_problem(verdict)
    if report.missing or verdict:
        raise typer.Exit(1)


@app.command()
def reproduce(
    plan: Annotated[str, typer.Option(help="Plan name (default) or plan YAML file")] = "default",
    out: Annotated[Path, typer.Option(help="Folder for everything reproduce writes")] = Path(
        "reproduce-output"
    ),
    workers: Annotated[int, typer.Option(min=1, max=MAX_WORKERS, help="Parallel episodes")] = 2,
    executor: Annotated[str, typer.Option(help="processes, threads, serial or ray")] = "processes",
    threads_per_worker: Annotated[
        int,
        typer.Option(
            min=1,
            max=MAX_THREADS_PER_WORKER,
            help="With processes: episodes run in threads in each worker",
        ),
    ] = 1,
    data_dir: Annotated[
        str | None,
        typer.Option(
            help="AVDN-format dataset folder, or sample / full (default: the plan's, the "
            "bundled sample)"
        ),
    ] = None,
    limit: Annotated[
        int | None, typer.Option(min=1, help="Episodes per split (a quick look)")
    ] = None,
    fail_on_error: Annotated[float, typer.Option(min=0.0, max=1.0, help=FAIL_ON_ERROR_HELP)] = 0.0,
    recordings: Annotated[
        bool,
        typer.Option(help="Save a few episodes per system as Rerun recordings (viewer extra)"),
    ] = True,
) -> None:
    """The main job: the paper's Table I and II, control figures and a summary, on the
    bundled sample (or --data-dir).

    Exits 1 when a run is incomplete, stopped early, or has more than --fail-on-error of
    its episodes in error (the tables are written either way, with the error rates).
    """
    from skyvln_eval.harness.commands import describe_report
    from skyvln_eval.harness.executors import EXECUTOR_KINDS
    from skyvln_eval.harness.plan import load_plan
    from skyvln_eval.harness.progress import RichRunProgress
    from skyvln_eval.harness.reproduce import reproduce as run_plan
    from skyvln_eval.harness.run import error_verdict

    if executor not in EXECUTOR_KINDS:  # checked before anything is written
        raise ConfigError(f"--executor: {UnknownNameError('executor', executor, EXECUTOR_KINDS)}")
    chosen = load_plan(plan, limit=limit, recordings=None if recordings else 0)
    # Text, not a Path, which drops the "./" of ./sample: that folder was taken for the
    # synthetic sample. The synthetic sets are built here, with a progress bar on first use.
    data_dir_argument(data_dir if data_dir is not None else chosen.data)
    progress = RichRunProgress(err_console)
    with _stoppable(progress):
        try:
            report = run_plan(
                chosen,
                out,
                workers,
                executor,
                data_dir,
                progress,
                threads_per_worker=threads_per_worker,
            )
        except RunStoppedError as stopped:  # a run's verdict, as `run` gives it: exit 1
            _echo_problem(f"error: {stopped}")
            raise typer.Exit(1) from None
    # Each run's account (what resume kept, set aside or ran now, its warnings), as `run`
    # prints it: a reproduction is several runs, and their notes are not in the tables.
    for run_report in report.reports:
        for line in describe_report(run_report):
            console.print(line, markup=False, highlight=False)
    for name in ("table1.md", "table2.md"):
        console.print(report.files[name].read_text(encoding="utf-8"))
    console.print(f"wrote {report.files['SUMMARY.md']} ({report.wall_s:.0f} s)")
    verdict = error_verdict(report.reports, fail_on_error)
    if verdict:
        _echo_problem(verdict)
    if not report.complete or verdict:
        raise typer.Exit(1)


@app.command()
def view(
    target: Annotated[
        Path,
        typer.Argument(
            help="A run directory (skyvln-eval run --out), a folder of them (reproduce's "
            "runs/<system>), one run MCAP, or an .rrd"
        ),
    ],
    episode: Annotated[
        list[str] | None,
        typer.Option("--episode", "-e", help="Episode ID or SPLIT/ID; repeat it (default: all)"),
    ] = None,
    save: Annotated[
        Path | None,
        typer.Option(help="Write FILE.rrd (several episodes: one recording each) or a folder"),
    ] = None,
    serve: Annotated[
        bool, typer.Option(help="Serve the web viewer on 127.0.0.1 (the default without --save)")
    ] = False,
    port: Annotated[int, typer.Option(min=0, max=65535, help="Web viewer port")] = 9090,
) -> None:
    """See episodes in the Rerun web viewer: map, 3-D flight, camera, texts, control plots.

    One recording per episode, built from its run MCAP only. Needs `pip install
    'skyvln-eval[viewer]'`. Rerun's usage analytics are off for what this starts (if you
    start `rerun` yourself, `rerun analytics disable` turns them off).
    """
    from skyvln_eval.viewer.commands import run_view

    run_view(target, episode or [], save, serve, port)


def _register_report_commands() -> None:
    # Implementations live in skyvln_eval.reports.commands; they import heavy modules lazily.
    from skyvln_eval.reports.commands import plot_app, score, table

    app.command()(score)
    app.command()(table)
    app.add_typer(plot_app, name="plot")


_register_report_commands()


class _PlainHelpCommand(TyperCommand):
    """A command whose help texts read as written: Rich markup escaped (``[viewer]`` would
    vanish as a style tag), and the paragraphs of its docstring unwrapped so that the
    terminal wraps them (Typer keeps the docstring's line breaks, which then break
    sentences in the middle of a narrower line)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        rich = typer.core.HAS_RICH and self.rich_markup_mode == "rich"
        self.help = _plain_text(self.help, rich, unwrap=True)
        for param in self.params:
            if isinstance(param, typer.core.TyperOption | typer.core.TyperArgument):
                param.help = _plain_text(param.help, rich, unwrap=False)


def _plain_text(text: str | None, rich: bool, unwrap: bool) -> str | None:
    from rich.markup import escape

    if text is None:
        return None
    if unwrap:  # paragraphs (blank-line separated) become one line each
        text = "\n\n".join(" ".join(p.split()) for p in text.split("\n\n"))
    return escape(text) if rich else text


def _plain_help_everywhere(group: typer.Typer) -> None:
    """Every command of ``group`` and of its sub-groups shows plain help (see above)."""
    for info in group.registered_commands:
        if info.cls in (None, TyperCommand):  # not a command class of its own
            info.cls = _PlainHelpCommand
    for sub in group.registered_groups:
        if sub.typer_instance is not None:
            _plain_help_everywhere(sub.typer_instance)


_plain_help_everywhere(app)


def main() -> None:
    """Entry point of the console script."""
    try:
        app()
    except SkyvlnError as exc:
        _echo_problem(f"error: {exc}")
        raise SystemExit(2) from None
    except OSError as exc:  # the machine's, not the toolkit's: a full disk, a permission
        from skyvln_eval.errors import describe_os_error

        _echo_problem(f"error: {describe_os_error(exc)}")
        raise SystemExit(2) from None
    except MemoryError:  # the machine's too: exit 1 would read as "episodes in error"
        _echo_problem(
            "error: out of memory (a memory limit, e.g. `ulimit -v`, or a full machine): "
            "free some memory or run with fewer workers; a run resumes where it stopped"
        )
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
