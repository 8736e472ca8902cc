"""``skyvln-eval reproduce``: run a plan and regenerate the paper's tables and figures.

Writes under the output directory:

- ``runs/``: one resumable run directory per (system, split) (results, run MCAPs, control logs);
- ``scores/scores.csv`` and ``scores/summary.csv``: every episode's scores and the means
  with 95% intervals (percentile bootstrap over whole trajectories; Wilson for a 0/1
  rate whose values are all alike; ``ci_method`` says which), under the stated metric
  conventions;
- ``tables/table1.{md,tex,csv}``, ``tables/table2.{md,tex,csv}`` (and ``*_ci.md`` with
  intervals), ``tables/control.md`` (safety and control of the flown systems) and
  ``tables/cost.md`` (LLM calls, tokens, cost and latency per backend);
- ``scores/tables.json``: each table's rows, order and notes (``skyvln-eval table`` on
  these scores makes the same tables from it);
- ``figures/``: the control figures of the static and dynamic obstacle cases, SR vs the
  success threshold, the NE distribution and trajectories over their maps;
  ``control_runs/``: the control logs the control figures are drawn from;
- ``recordings/``: the first finished episodes of every system as Rerun recordings;
- ``dataset_summary.json`` and ``SUMMARY.md``, which links every file in ``files`` and says
  which runs fill two table rows.

Interrupted, it resumes: finished episodes are not run again.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pandas as pd

from skyvln_eval.agent.config import LLM_AGENTS, AgentConfig
from skyvln_eval.avdn.constants import SPLITS, annotation_file_name
from skyvln_eval.avdn.loader import load_split
from skyvln_eval.avdn.summary import SplitSummary, summarise_split
from skyvln_eval.errors import AvdnValidationError, RunStoppedError
from skyvln_eval.fileio import atomic_write_json, atomic_write_text, ensure_directory
from skyvln_eval.harness.executors import ExecutorKind, make_executor
from skyvln_eval.harness.oracle import is_oracle
from skyvln_eval.harness.plan import PlannedRun, ReproducePlan, planned_runs
from skyvln_eval.harness.preflight import check_local_servers
from skyvln_eval.harness.run import (
    RUN_INVALID_HINT,
    Progress,
    RunJob,
    RunReport,
    execute_jobs,
    is_synthetic_data,
    prepare_job,
    resolve_data_dir,
    speed_cap_note,
)
from skyvln_eval.metrics import MetricConventions, score_results, summarise
from skyvln_eval.metrics.cost import UNKNOWN_IF_ANY_UNKNOWN
from skyvln_eval.metrics.records import EpisodeResult
from skyvln_eval.metrics.scores_io import summary_csv_text, write_scores
from skyvln_eval.reports import TABLE_I, TABLE_II, to_csv, to_latex, to_markdown
from skyvln_eval.reports.paper_tables import (
    STAND_IN_MARKERS,
    model_label,
    oracle_label,
    paper_table,
    stand_in_kind,
    table_metrics,
)
from skyvln_eval.reports.table_layout import (
    LAYOUT_FILE,
    ReproducedTables,
    TableLayout,
    write_layout,
)
from skyvln_eval.reports.tables import fixed

TABLE_METRICS = ("success", "oracle_success", "spl", "gp_m", "ne_m", "path_length_m")
HEALTH_METRICS = (
    "status_ok",
    "status_degraded",
    "status_error",
    "fallback_rate",
    "llm_call_failure_rate",
    "wall_s",
)
#: How a table column combines its episodes' values.
Aggregate = Literal["mean", "min", "max", "share"]
#: The control table's columns: (score column, header, how episodes are combined). A
#: header says how: a mean over episodes of their minimum clearance would hide the one
#: that collided, so the worst episode has its own column.
CONTROL_COLUMNS: tuple[tuple[str, str, Aggregate], ...] = (
    ("collided", "collided episodes/%", "share"),
    ("min_clearance_m", "min keep-out clearance/m, worst episode", "min"),
    ("min_clearance_m", "min keep-out clearance/m, episode mean", "mean"),
    ("solve_failures", "solve failures per episode", "mean"),
    ("soft_steps", "steps whose plan relaxed the obstacle constraint, per episode", "mean"),
    (
        "constraint_violation_steps",
        "steps inside the keep-out clearance or past a limit, per episode",
        "mean",
    ),
    (
        "segments_cut_short",
        "segments ended at the time limit short of their target, per episode",
        "mean",
    ),
    ("rmse_x_m", "RMSE x/m, episode mean", "mean"),
    ("rmse_y_m", "RMSE y/m, episode mean", "mean"),
    ("rmse_z_m", "RMSE z/m, episode mean", "mean"),
    ("solve_time_mean_ms", "solve time/ms, episode mean", "mean"),
    ("solve_time_p95_ms", "solve time p95/ms, worst episode", "max"),
)
CONTROL_METRICS = tuple(dict.fromkeys(metric for metric, _, _ in CONTROL_COLUMNS))
COST_METRICS = (
    "llm_calls",
    "llm_requests",  # every request sent: retries and forms the server refused included
    "llm_refused_requests",
    "llm_failed_calls",
    "llm_parse_failures",
    "llm_repairs",
    "fallback_decisions",
    "llm_prompt_tokens",
    "llm_completion_tokens",
    "llm_cost_usd",
    "llm_cost_lower_usd",
    "llm_latency_s",
    "wall_s",
)

#: Score columns that are wall-clock measurements: they vary from run to run, where every
#: other value of the scores and tables is the same for the same seed and inputs.
WALL_CLOCK_METRICS = (
    "wall_s",
    "llm_latency_s",
    "llm_queue_s",
    "solve_time_mean_ms",
    "solve_time_p95_ms",
)
#: The footnote part that says a table's timing columns are measured, not computed.
VARY_RUN_TO_RUN = "measured wall-clock times (they vary from run to run)"


def setting_note(plan: ReproducePlan) -> str:
    """What the agents could sense and ask, for the tables' captions."""
    asks = plan.commander.max_questions
    commander = (
        f"a simulated commander who knows the goal (the end of the ground truth scored) "
        f"answers up to {asks} clarification question(s) per episode with the way and "
        "distance to it, or that the drone is there (whatever was asked)"
        if asks
        else "no commander answers questions"
    )
    flown = [s.label for s in plan.table1.systems if s.mode == "dynamics"]
    stepped = [s.label for s in plan.table1.systems if s.mode != "dynamics"]
    if plan.table2.system.mode == "dynamics":
        flown.append("Table II's rows")
    else:
        stepped.append("Table II's rows")
    how = ""
    if flown:  # which rows flew through the obstacles, and which took AVDN's step
        how = f"; flown by their controllers ({plan.dynamics.plant.describe()}): {', '.join(flown)}"
        if stepped:
            how += f"; the official AVDN step (no flight, no obstacles): {', '.join(stepped)}"
    limit = (
        f" Episodes: the first {plan.limit} of each split (a quick look: limit {plan.limit})."
        if plan.limit
        else ""
    )
    return f"{_data_note(plan.data)} Sensors: {plan.sensors.describe()}; {commander}{how}.{limit}"


def _data_note(data: str) -> str:
    """Which data the tables are over: the synthetic sets are in AVDN's format, not AVDN."""
    synthetic = {"sample": "the synthetic sample", "full": "the AVDN-sized synthetic set"}
    if data in synthetic:
        return (
            f"Data: {synthetic[data]} (AVDN's format, not its imagery or dialogs; its "
            "test_unseen keeps the whole ground truth, which AVDN's release withholds)."
        )
    return f"Data: {Path(data).name} (AVDN format)."


def table1_label(label: str, agent: AgentConfig) -> tuple[str, str | None]:
    """A Table I row label that says what answered the agent's LLM calls, and its footnote.

    The oracle is marked as such wherever its row is shown (the control table and
    SUMMARY.md too, not only Table I); other agents without LLM modules keep their label;
    stand-ins get a marker whose footnote says so; a real model is named
    (``Full (openai:gpt-4o)``) unless the label already names it.
    """
    if is_oracle(agent.name):
        return oracle_label(label), None
    if agent.name not in LLM_AGENTS:
        return label, None
    backend = agent.llm.answered_by
    kind = stand_in_kind(backend)
    if kind is not None:
        marker, note = STAND_IN_MARKERS[kind]
        return f"{label} {marker}", note
    return model_label(label, backend), None


#: The tables' titles, as SUMMARY.md names them.
TABLE_TITLES = {"table1": "Table I", "table2": "Table II"}


@dataclass
class ReproduceReport:
    """What reproduce ran and wrote. ``run_rows``: for each of ``reports``, the table rows
    its episodes fill, ``(table title, row label as the table shows it)``; a run can fill
    two (Table I's Full and Table II's rule-based row are one run)."""

    out_dir: Path
    reports: list[RunReport]
    run_rows: list[tuple[tuple[str, str], ...]] = field(default_factory=list)
    files: dict[str, Path] = field(default_factory=dict)
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return all(r.complete for r in self.reports)


def _row_labels(planned: PlannedRun, table: str) -> list[str]:
    """The rows ``planned`` fills in ``table``, labelled as the table shows them (Table I
    marks a stand-in's rows, ``Full †``)."""
    labels = [label for t, label in planned.rows if t == table]
    if table == "table1":
        return [table1_label(label, planned.config.agent)[0] for label in labels]
    return labels


def _labelled(
    planned: PlannedRun, results: Sequence[EpisodeResult], table: str
) -> list[EpisodeResult]:
    labels = _row_labels(planned, table)
    return [dataclasses.replace(r, system=label) for label in labels for r in results]


def _write_tables(
    scores: pd.DataFrame,
    summary: pd.DataFrame,
    plan: ReproducePlan,
    table1: tuple[list[str], list[str]],
    table2_rows: list[str],
    conventions: MetricConventions,
    tables_dir: Path,
    withheld: Sequence[str] = (),
) -> dict[str, Path]:
    """Tables I and II, as :func:`paper_table` makes them for every caller (references,
    stand-in markers and notes come from the scores themselves)."""
    files: dict[str, Path] = {}
    table1_rows, table1_notes = table1
    setting = [setting_note(plan)]
    # Table II is over the plan's split (the paper's: the unseen test split).
    table2 = TABLE_II.over(plan.table2.split)
    layouts = {
        "table1": TableLayout(tuple(table1_rows), (*setting, *table1_notes)),
        "table2": TableLayout(
            tuple(table2_rows),
            tuple(setting),
            () if table2.groups == TABLE_II.groups else (plan.table2.split,),
        ),
    }
    # Which rows and notes each table has, for `skyvln-eval table` on these scores.
    layout = ReproducedTables(layouts, plan.resamples, plan.seed, tuple(withheld), plan.ci_unit)
    files[LAYOUT_FILE] = write_layout(tables_dir.parent / "scores", layout)
    for name, spec in (("table1", TABLE_I), ("table2", table2)):
        rows, notes = list(layouts[name].rows), list(layouts[name].notes)
        shape = functools.partial(
            paper_table, scores, spec, conventions, summary=summary, rows=rows, notes=notes,
            withheld=withheld,
        )  # fmt: skip
        table = shape()
        for suffix, render in (("md", to_markdown), ("tex", to_latex), ("csv", to_csv)):
            path = tables_dir / f"{name}.{suffix}"
            atomic_write_text(path, render(table))
            files[f"{name}.{suffix}"] = path
        if "ci_low" in summary.columns:
            path = tables_dir / f"{name}_ci.md"
            atomic_write_text(path, to_markdown(shape(show_ci=True)))
            files[f"{name}_ci.md"] = path
    return files


def _featured_row(plan: ReproducePlan, shown: Sequence[str]) -> str:
    """The Table I row whose trajectories are drawn: Table II's system, else the last agent
    row (never the oracle)."""
    rows = list(zip(plan.table1.systems, shown, strict=True))
    for system, label in rows:
        if system.label == plan.table2.system.label:
            return label
    agents = [label for system, label in rows if not is_oracle(str(system.agent.get("name")))]
    return agents[-1] if agents else shown[-1]


def _table1_rows(runs: Sequence[PlannedRun], plan: ReproducePlan) -> tuple[list[str], list[str]]:
    """Table I's row labels (with stand-in markers) in plan order, and their footnotes."""
    agents = {
        label: planned.config.agent
        for planned in runs
        for table, label in planned.rows
        if table == "table1"
    }
    labelled = [table1_label(s.label, agents[s.label]) for s in plan.table1.systems]
    notes = [note for _, note in labelled if note]
    # What each SkyVLN row has switched off, whatever its label says ("w NMPC" is the
    # agent without HSD and memory, flown with the NMPC).
    switched_off: dict[str, list[str]] = {}
    for system, (shown, _) in zip(plan.table1.systems, labelled, strict=True):
        agent = agents[system.label]
        if agent.name == "skyvln":
            off = [part for part, on in (("HSD", agent.hsd), ("TrackBack memory", agent.tbma))
                   if not on]  # fmt: skip
            if off:
                switched_off.setdefault(" and ".join(off), []).append(shown)
    if switched_off:
        notes.append(
            "SkyVLN parts switched off: "
            + "; ".join(f"{', '.join(rows)}: {parts}" for parts, rows in switched_off.items())
            + "."
        )
    # A controller slower than the reference is a confound a reader must see.
    for planned in runs:
        cap = speed_cap_note(planned.config)
        labels = [label for table, label in planned.rows if table == "table1"]
        if cap and labels:
            notes.append(f"{', '.join(labels)}: {cap}")
    return [label for label, _ in labelled], list(dict.fromkeys(notes))


#: Decimals of the columns that need more than 3: a cost per episode is a few thousandths
#: of a dollar or less (0.0014 and 0.0006 would both read 0.001); Table II shows 4.
_DECIMALS: dict[str, int] = {"llm_cost_usd": 6, "llm_cost_lower_usd": 6}


def _metric_table(
    scores: pd.DataFrame,
    systems: Sequence[str],
    columns: Sequence[tuple[str, str, Aggregate]],
    title: str,
    note: str = "",
    counted: str | None = None,
) -> str:
    """A Markdown table of ``columns`` (score column, header, how its episodes combine);
    ``counted``: a 0/1 column saying which episodes the values come from (the flown ones
    of a control table), their count shown as "k of n" when some have none."""
    present = [c for c in columns if c[0] in scores.columns]
    sel = scores[scores["system"].isin(systems)]
    unknown_if_any = UNKNOWN_IF_ANY_UNKNOWN
    lines = [
        f"### {title}",
        "",
        "| system | episodes | " + " | ".join(header for _, header, _ in present) + " |",
        "|---|---|" + "---|" * len(present),
    ]
    for system in systems:
        group = sel[sel["system"] == system]
        if group.empty:
            continue
        cells = []
        for metric, _, how in present:
            values = group[metric].dropna().astype(float)
            if metric in unknown_if_any and len(values) < len(group):
                cells.append("n/a")  # some episode's value is unknown: so is the mean
            elif not len(values):
                cells.append("-")
            else:
                # A share is the mean of 0/1 values, in percent.
                value = 100.0 * values.mean() if how == "share" else getattr(values, how)()
                cells.append(fixed(value, _DECIMALS.get(metric, 3)))  # as the tables round
        episodes = str(len(group))
        if counted is not None and counted in group.columns:
            with_values = int(group[counted].fillna(False).astype(bool).sum())
            if with_values < len(group):
                episodes = f"{with_values} of {len(group)}"
        lines.append(f"| {system} | {episodes} | " + " | ".join(cells) + " |")
    return "\n".join([*lines, *(["", note] if note else [])]) + "\n"


def _one_split_note(rows: Sequence[str], split: str) -> str:
    return f", Table II's ({', '.join(rows)}) are of {split} alone" if rows else ""


def _control_figures(plan: ReproducePlan, out_dir: Path) -> dict[str, Path]:
    from skyvln_eval.control import record_paper_runs
    from skyvln_eval.metrics import read_control_log
    from skyvln_eval.reports import control_figure, save_figure
    from skyvln_eval.reports.control_figures import control_figure_name

    spec = plan.control_figures
    if not spec.controllers or not spec.cases:  # a plan may leave the control figures out
        return {}
    paths = record_paper_runs(out_dir / "control_runs", spec.controllers, spec.cases, plan.seed)
    # The logs the figures are drawn from, for SUMMARY.md to link.
    files = {f"control_runs/{path.name}": path for path in sorted(paths.values())}
    for case in spec.cases:
        frames = [read_control_log(p) for (_, c), p in paths.items() if c == case]
        log = pd.concat(frames, ignore_index=True)
        figure = control_figure(log, title=f"6-DOF curves and errors, {case} obstacle case")
        for suffix in ("png", "pdf"):
            # Named from the log's scenario, as `plot control` names a figure of these logs.
            name = control_figure_name(str(log["scenario"].iloc[0]), suffix)
            files[name] = save_figure(figure, out_dir / "figures" / name)
    return files


def _navigation_figures(
    scores: pd.DataFrame, systems: Sequence[str], conventions: MetricConventions, figures_dir: Path
) -> dict[str, Path]:
    from skyvln_eval.reports import ne_distribution_figure, save_figure, sr_vs_threshold_figure

    present = [s for s in systems if s in set(scores["system"])]
    return {
        "sr_vs_threshold.png": save_figure(
            sr_vs_threshold_figure(scores, conventions, present),
            figures_dir / "sr_vs_threshold.png",
        ),
        "ne_distribution.png": save_figure(
            ne_distribution_figure(scores, present), figures_dir / "ne_distribution.png"
        ),
    }


def _trajectory_figures(
    results: Sequence[EpisodeResult], data_dir: Path, count: int, figures_dir: Path
) -> dict[str, Path]:
    from skyvln_eval.reports import save_figure, trajectory_figure
    from skyvln_eval.worlds.loading import load_world

    files: dict[str, Path] = {}
    chosen = [r for r in results if r.status == "ok" and len(r.visited_views)][:count]
    for result in chosen:
        split = load_split(data_dir, result.split)
        record = next(r for r in split.records if r.episode_id == result.episode_id)
        world = load_world(data_dir, record.map_name, record.georef)
        figure = trajectory_figure(
            world,
            result.gt_path_corners,
            result.visited_views,
            title=f"{result.system}: {result.split} {result.episode_id}",
        )
        name = f"trajectory_{result.episode_id}.png"
        files[name] = save_figure(figure, figures_dir / name)
    return files


def _recordings(
    plan: ReproducePlan, runs: Sequence[PlannedRun], jobs: Sequence[RunJob], out_dir: Path
) -> tuple[dict[str, Path], list[str]]:
    """The first ``plan.recordings`` finished episodes of each system as Rerun recordings."""
    if plan.recordings == 0:
        return {}, []
    from skyvln_eval.viewer.examples import write_examples

    chosen: dict[str, tuple[Path, list[tuple[str, str]]]] = {}
    for planned, job in zip(runs, jobs, strict=True):
        label = planned.rows[0][1]
        if label not in chosen:  # a system's first run (its first split) is enough
            done = sorted((r.split, r.episode_id) for r in job.store.results() if r.status == "ok")
            chosen[label] = (planned.run_dir, done[: plan.recordings])
    return write_examples(chosen, out_dir / "recordings")


def _dataset_summary(data_dir: Path) -> list[SplitSummary]:
    try:
        return [
            summarise_split(load_split(data_dir, split))
            for split in SPLITS
            if (data_dir / "annotations" / annotation_file_name(split)).is_file()
        ]
    except AvdnValidationError as error:  # what a run says: reproduce cannot skip records
        raise AvdnValidationError(error.issues, RUN_INVALID_HINT) from None


def reproduce(
    plan: ReproducePlan,
    out_dir: str | Path,
    workers: int = 2,
    executor: ExecutorKind = "processes",
    data: str | None = None,
    progress: Progress | None = None,
    threads_per_worker: int = 1,
) -> ReproduceReport:
    """Run every planned system, then write scores, tables, figures and the summary.

    ``threads_per_worker`` runs that many episodes in threads in each worker process
    (for remote LLMs: their waits overlap)."""
    out_dir = ensure_directory(out_dir, "output folder")
    started = time.perf_counter()
    plan = plan.model_copy(update={"data": data or plan.data})  # what the notes name
    data_dir = resolve_data_dir(plan.data)
    # First: it refuses a plan whose model lacks its API key before anything is written,
    # and one whose model is served on this machine where nothing listens (each run
    # checks too, but after the run folders before it were made).
    # A synthetic set is named, not located: its runs' configs read the same on every
    # machine and from every cache folder (the name resolves to one byte-identical set).
    run_data = plan.data if is_synthetic_data(plan.data) else str(data_dir)
    runs = planned_runs(plan, out_dir, workers, executor, run_data)
    for planned in runs:
        check_local_servers(planned.config.agent, repr(planned.config.system))
    datasets = _dataset_summary(data_dir)
    atomic_write_json(
        out_dir / "dataset_summary.json",
        # The data as the plan names it ("sample", or the folder given), not where this
        # machine's cache keeps it: the file is the same wherever it is made.
        {"data": plan.data, "splits": [dataclasses.asdict(s) for s in datasets]},
        indent=1,
    )
    jobs: list[RunJob] = []
    try:
        for planned in runs:
            jobs.append(prepare_job(planned.config, planned.run_dir))
    except BaseException:  # e.g. a run directory in use: let go of the ones already held
        for job in jobs:
            job.release()
        raise
    reports = execute_jobs(
        jobs,
        make_executor(executor, workers, threads_per_worker=threads_per_worker),
        progress,
        f"reproduce ({plan.name})",
    )
    stopped = [f"{r.system}: {r.stopped}" for r in reports if r.stopped]
    if stopped:  # the tables need every run's episodes: say why, not what is missing
        raise RunStoppedError(
            f"reproduce ({plan.name}) stopped before its tables, as a run did: "
            + "; ".join(stopped)
            + f". The episodes recorded are kept under {out_dir / 'runs'}: the same command "
            "goes on from them once that is fixed."
        )
    run_rows = [
        tuple((title, label) for table, title in TABLE_TITLES.items()
              for label in _row_labels(planned, table))
        for planned in runs
    ]  # fmt: skip
    report = ReproduceReport(out_dir, reports, run_rows)
    report.files["dataset_summary.json"] = out_dir / "dataset_summary.json"
    results: list[EpisodeResult] = []
    table2_rows: list[str] = []
    stand_ins: list[str] = []  # Table II rows answered by a stand-in
    for planned, job in zip(runs, jobs, strict=True):
        stored = job.store.results()
        results += _labelled(planned, stored, "table1") + _labelled(planned, stored, "table2")
        labels = [label for table, label in planned.rows if table == "table2"]
        table2_rows += labels
        if stand_in_kind(planned.config.agent.llm.backend) is not None:
            stand_ins += labels
    conventions = MetricConventions()
    # Episodes whose ground truth is withheld ran (their routes are in the run logs) but
    # cannot be scored: their splits show "withheld" (all of them: score_results says why).
    withheld = sorted({r.split for r in results if not r.has_ground_truth})
    scored = [r for r in results if r.has_ground_truth]
    scores = score_results(scored or results, conventions)
    metrics = dict.fromkeys(
        (
            *TABLE_METRICS,
            *HEALTH_METRICS,
            *CONTROL_METRICS,
            *COST_METRICS,
            *table_metrics(TABLE_I),
            *table_metrics(TABLE_II),
        )
    )
    summary = summarise(
        scores,
        [m for m in metrics if m in scores],
        plan.resamples,
        seed=plan.seed,
        ci_unit=plan.ci_unit,
        warn_errors=False,  # the tables and SUMMARY.md show them
    )
    write_scores(out_dir / "scores" / "scores.csv", scores, conventions)
    atomic_write_text(out_dir / "scores" / "summary.csv", summary_csv_text(summary, conventions))
    report.files |= {
        "scores.csv": out_dir / "scores" / "scores.csv",
        "summary.csv": out_dir / "scores" / "summary.csv",
    }
    tables_dir = out_dir / "tables"
    table1 = _table1_rows(runs, plan)
    featured = _featured_row(plan, table1[0])
    report.files |= _write_tables(
        scores, summary, plan, table1, table2_rows, conventions, tables_dir, withheld
    )
    table1_rows = table1[0]
    flown = [
        label
        for label, system in zip(table1_rows, plan.table1.systems, strict=True)
        if system.mode == "dynamics"
    ]
    # Table II's backends fly too when its system does (a crash there is one all the same).
    flown_on_one_split = table2_rows if plan.table2.system.mode == "dynamics" else []
    flown += [label for label in flown_on_one_split if label not in flown]
    atomic_write_text(
        tables_dir / "control.md",
        _metric_table(
            scores,
            flown,
            CONTROL_COLUMNS,
            "Safety and control (flown systems)",
            "Keep-out clearance: how far the drone stayed outside the nearest obstacle's "
            "keep-out sphere (its radius plus the safety margin); below 0 it was inside that "
            "sphere, a collision is inside the obstacle itself. Episodes: those that flew "
            '("k of n": the others ended before any flight); Table I\'s rows pool their '
            f"splits{_one_split_note(flown_on_one_split, plan.table2.split)}. A dash: no "
            "episode has the value (relaxed steps of a controller without an obstacle "
            "constraint, as the PID; clearance where no obstacle flew). The solve-time "
            f"columns are {VARY_RUN_TO_RUN}.",
            counted="has_control",
        ),
    )
    atomic_write_text(
        tables_dir / "cost.md",
        _metric_table(
            scores,
            table2_rows,
            [(metric, metric, "mean") for metric in COST_METRICS],
            f"LLM cost per episode, mean over episodes ({plan.table2.split})",
            # A stand-in has no tokenizer: its counts are not comparable with a model's.
            (
                f"Tokens of {', '.join(stand_ins)}: estimates (four characters a token), not "
                "counted by a model; a stand-in costs nothing. "
                if stand_ins
                else ""
            )
            + f"llm_latency_s and wall_s are {VARY_RUN_TO_RUN}.",
        ),
    )
    report.files |= {"control.md": tables_dir / "control.md", "cost.md": tables_dir / "cost.md"}
    figures_dir = out_dir / "figures"
    report.files |= _control_figures(plan, out_dir)
    report.files |= _navigation_figures(scores, table1_rows, conventions, figures_dir)
    full = [r for r in results if r.system == featured and r.split == plan.table2.split]
    report.files |= _trajectory_figures(full, data_dir, plan.trajectory_figures, figures_dir)
    recordings, report.notes = _recordings(plan, runs, jobs, out_dir)
    report.files |= recordings
    report.wall_s = time.perf_counter() - started
    from skyvln_eval.harness.summary_page import write_summary_page

    report.files["SUMMARY.md"] = write_summary_page(report, plan, datasets, conventions, scores)
    return report
