"""The ``score``, ``table`` and ``plot`` commands (registered in :mod:`skyvln_eval.cli`).

Each parses options, calls :mod:`skyvln_eval.metrics` / :mod:`skyvln_eval.reports` and
writes files atomically; heavy imports happen inside the commands so ``skyvln-eval
--help`` stays fast.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from skyvln_eval.avdn.constants import EpisodeMode
from skyvln_eval.bounds import MAX_BOOTSTRAP_RESAMPLES, MAX_BOOTSTRAP_SEED
from skyvln_eval.errors import ConfigError, DataError, listed

if TYPE_CHECKING:
    import pandas as pd

    from skyvln_eval.metrics import EpisodeResult, MetricConventions
    from skyvln_eval.metrics.aggregate import CiUnit

plot_app = typer.Typer(
    help="Figures: control curves, SR vs threshold, NE distribution, maps.", no_args_is_help=True
)

SUMMARY_METRICS = ("success", "oracle_success", "spl", "gp_m", "oracle_gp_m", "ne_m",
                   "path_length_m", "r2r_sr", "r2r_osr", "r2r_spl", "r2r_ne_m", "r2r_tl_m",
                   "ndtw", "sdtw", "cls",
                   "status_error", "status_degraded", "fallback_rate", "llm_call_failure_rate",
                   "llm_cost_usd", "llm_latency_s", "collided", "min_clearance_m",
                   "solve_failures", "soft_steps", "constraint_violation_steps",
                   "segments_cut_short")  # fmt: skip
#: What the terminal table shows (summary.csv has every metric above).
#: The metrics the score printout shows, under short headers (the tables' names): the
#: column names of scores.csv would be cut to fit ("oracle_succe…"); the note under the
#: printout names the column of each header.
PRINTED_METRICS: dict[str, str] = {
    "success": "SR",
    "oracle_success": "OSR",
    "spl": "SPL",
    "gp_m": "GP",
    "ne_m": "NE",
    "path_length_m": "TL",
    "status_error": "Error",
    "status_degraded": "Degraded",
    "fallback_rate": "Fallback",
    "llm_cost_usd": "Cost",
    "collided": "Collided",
}


def _cell(by_metric: Any, metric: str) -> str:
    """A summary mean as the tables show it: their decimals, "n/a" for unknown, "error"
    where every episode ended in error and the metric scores them as failures (a 0 there
    would read as a result), the tables' marker where some did."""
    from skyvln_eval.reports.tables import HEALTH_METRICS, SOME_ERRORS, TABLE_II, fixed

    if metric not in by_metric.index:
        return "-"
    mean = float(by_metric.loc[metric, "mean"])
    errors = 0.0
    if metric not in HEALTH_METRICS and "status_error" in by_metric.index:
        errors = float(by_metric.loc["status_error", "mean"])
    if errors >= 100.0:
        return "error"
    if math.isnan(mean):
        return "n/a"
    text = fixed(mean, TABLE_II.digits_of(metric, 2))
    return text + (SOME_ERRORS if errors > 0.0 else "")


def _mode(mode: str) -> EpisodeMode:
    if mode == "andh":
        return "andh"
    if mode == "andh-full":
        return "andh-full"
    raise ConfigError(f"--mode must be 'andh' or 'andh-full', not {mode!r}")


def _conventions(
    threshold_m: float, distance: str, non_strict: bool, legacy_gp: bool, collisions_succeed: bool
) -> MetricConventions:
    from skyvln_eval.metrics import MetricConventions

    if distance not in ("2d", "3d"):
        raise ConfigError(f"--distance must be '2d' or '3d', not {distance!r}")
    return MetricConventions(
        distance="2d" if distance == "2d" else "3d",
        threshold_m=threshold_m,
        strict_threshold=not non_strict,
        legacy_gp=legacy_gp,
        collision_fails=not collisions_succeed,
    )


def _input_files(path: Path) -> list[Path]:
    """The files to score for ``path``: a run directory's results.jsonl, those of a folder
    of run directories (as reproduce's ``runs/<system>``), else ``path``; refuses what
    cannot be scored, saying what it is and what to give instead."""
    from skyvln_eval.harness.run import CONFIG_FILE, REPORT_FILE, VERSIONS_FILE
    from skyvln_eval.harness.store import RESULTS_FILE

    run_files = {
        REPORT_FILE: "the report of a run (episodes by status, errors), not its results",
        CONFIG_FILE: "the configuration of a run, not its results",
        VERSIONS_FILE: "the library versions of a run, not its results",
    }
    if path.is_dir():
        if (path / RESULTS_FILE).is_file():
            return [path / RESULTS_FILE]
        from skyvln_eval.harness.run_check import run_directories_at

        # The run directories below it, at any depth: a reproduction's output or its runs/.
        runs = [d / RESULTS_FILE for d in run_directories_at(path) if (d / RESULTS_FILE).is_file()]
        if runs:
            return runs
        raise DataError(
            f"{path}: a directory without {RESULTS_FILE}, here or below, so not a run "
            "directory nor a folder of them (or runs that recorded no episode yet); give a run "
            "directory, a results file (.jsonl, .parquet) or a predictions file (.npy, .json)"
        )
    if not path.exists():
        raise DataError(f"{path}: no such file or directory")
    if path.name in run_files:
        raise DataError(
            f"{path}: {run_files[path.name]}; score the run directory {path.parent} "
            f"(or {path.parent / RESULTS_FILE})"
        )
    if path.suffix not in (".jsonl", ".parquet", ".npy", ".json"):
        raise DataError(
            f"{path}: neither a results file (.jsonl, .parquet), a predictions file "
            "(.npy official, .json) nor a run directory"
        )
    return [path]


def _load_results(
    paths: list[Path],
    data_dir: Path | None,
    split: str | None,
    mode: str,
    system: str | None,
    allow_incomplete: bool = False,
) -> list[tuple[str, list[EpisodeResult]]]:
    """Each input's name and rows (no episode of a system, split and mode in two of them).
    A predictions file that misses episodes (with ``allow_incomplete``) is not warned of
    here: the coverage check against ``data_dir`` (which predictions need) names them."""
    from skyvln_eval.metrics import (
        ground_truth_episodes,
        read_predictions,
        results_from_predictions,
    )
    from skyvln_eval.metrics.results_io import check_unique_files, read_result_rows

    episode_mode = _mode(mode)  # a typo is refused whatever the inputs
    sources = []
    files = [file for path in paths for file in _input_files(path)]
    if not any(file.suffix in (".npy", ".json") for file in files):
        # Result rows carry their own split, mode and system: these would be ignored.
        given = [
            flag for flag, value in (("--split", split), ("--system", system)) if value is not None
        ] + (["--mode"] if episode_mode != "andh" else [])
        if given:
            raise ConfigError(
                f"{', '.join(given)}: only for predictions files (.npy, .json); run results "
                "carry their own split, mode and system"
            )
    for path in files:
        if path.suffix in (".jsonl", ".parquet"):
            # Every row: the coverage check counts a row that only records the run
            # stopping as a missing episode, and says so.
            sources.append((str(path), read_result_rows(path)))
            continue
        if data_dir is None or split is None:
            raise ConfigError(
                f"{path}: predictions need --data-dir and --split for their ground truth"
            )
        episodes = ground_truth_episodes(data_dir, split, episode_mode)
        predictions = read_predictions(path)
        label = system or path.stem
        rows = results_from_predictions(
            predictions, episodes, label, split, episode_mode, allow_missing=allow_incomplete
        )
        sources.append((str(path), rows))
    check_unique_files(sources)
    return sources


#: ``--ci-unit`` of ``score`` and ``table``.
CiUnitOption = Annotated[
    str | None,
    typer.Option(
        help="What the intervals resample: 'episode', or 'trajectory' (the rounds of a "
        "dialog together: they share a route, so episode intervals are too narrow); default: "
        "trajectory, or for table the reproduction's"
    ),
]


def score(
    results: Annotated[
        list[Path],
        typer.Argument(
            help="Run directories, result rows (.jsonl/.parquet) or predictions "
            "(.npy official, .json)"
        ),
    ],
    out: Annotated[Path, typer.Option(help="Folder for scores.csv and summary.csv")] = Path(
        "scores"
    ),
    data_dir_text: Annotated[
        str | None,
        typer.Option(
            "--data-dir",
            help="AVDN-format dataset (or sample / full): GT for predictions; completeness "
            "check for results (a run directory's: the episodes its config selects, from "
            "this dataset)",
        ),
    ] = None,
    split: Annotated[
        str | None, typer.Option(help="Split of the predictions (with --data-dir)")
    ] = None,
    mode: Annotated[str, typer.Option(help="Episode mode: andh or andh-full")] = "andh",
    system: Annotated[
        str | None, typer.Option(help="Row label for predictions (default: file name)")
    ] = None,
    threshold_m: Annotated[
        float, typer.Option(help="R2R success radius and nDTW/CLS d_th, metres")
    ] = 20.0,
    distance: Annotated[
        str, typer.Option(help="R2R distances on '2d' centres or '3d' (height = edge/2)")
    ] = "2d",
    non_strict: Annotated[
        bool, typer.Option("--non-strict", help="R2R success when NE <= threshold (default <)")
    ] = False,
    legacy_gp: Annotated[
        bool, typer.Option("--legacy-gp", help="Official GP against G[N-2] (pre-Nov-2023 code)")
    ] = False,
    collisions_succeed: Annotated[
        bool,
        typer.Option(
            "--collisions-succeed",
            help="Score flights that touched an obstacle on their views alone (default: "
            "they never succeed)",
        ),
    ] = False,
    resamples: Annotated[
        int,
        typer.Option(
            min=0,
            max=MAX_BOOTSTRAP_RESAMPLES,
            help="Bootstrap resamples for the 95% CIs (0: no CIs)",
        ),
    ] = 1000,
    seed: Annotated[int, typer.Option(min=0, max=MAX_BOOTSTRAP_SEED, help="Bootstrap seed")] = 0,
    ci_unit: CiUnitOption = None,
    allow_incomplete: Annotated[
        bool,
        typer.Option(
            "--allow-incomplete",
            help="Score a run that lacks some of its episodes (saying how many), instead of "
            "refusing it",
        ),
    ] = False,
) -> None:
    """Score results or predictions: per-episode scores and a per-system summary with CIs.

    The results of a run directory must cover every episode its config selects (its
    splits, episodes and limit); other results, given --data-dir, every episode of their
    split. An incomplete run is refused unless --allow-incomplete.
    """
    from skyvln_eval.fileio import atomic_write_text, ensure_directory
    from skyvln_eval.metrics import score_results, summarise
    from skyvln_eval.metrics.scores_io import summary_csv_text, write_scores
    from skyvln_eval.reports.run_coverage import covered_results, long_path_warnings
    from skyvln_eval.reports.table_layout import LAYOUT_FILE, read_layout

    if out.exists() and not out.is_dir():  # said now, not after the scoring
        raise ConfigError(f"--out {out} is an existing file, not a folder: name a folder")
    data_dir = None if data_dir_text is None else _data_dir(data_dir_text)
    conventions = _conventions(threshold_m, distance, non_strict, legacy_gp, collisions_succeed)
    sources = _load_results(results, data_dir, split, mode, system, allow_incomplete)
    loaded, warnings = covered_results(sources, data_dir, allow_incomplete)
    warnings += long_path_warnings(sources)
    scores = score_results(loaded, conventions)
    metrics = [m for m in SUMMARY_METRICS if m in scores]
    summary = summarise(  # its printout shows the errors: no warning
        scores, metrics, resamples, seed=seed, ci_unit=_ci_unit(ci_unit), warn_errors=False
    )
    ensure_directory(out, "--out")
    # Reproduce's layout of the scores these replace: kept while it places every system
    # scored (the same runs scored again, say with another threshold), else removed: the
    # tables made from these scores left the systems it did not know out, without a word.
    layout = out / LAYOUT_FILE
    if layout.is_file():
        placed = {row for t in read_layout(layout).tables.values() for row in t.rows}
        if not set(scores["system"].astype(str)) <= placed:
            layout.unlink()
            typer.echo(f"removed {layout}: it laid out other systems than these scores'")
    write_scores(out / "scores.csv", scores, conventions, warnings)
    atomic_write_text(out / "summary.csv", summary_csv_text(summary, conventions, warnings))
    _print_summary(summary, scores, conventions.describe(), warnings)
    typer.echo(f"wrote {out / 'scores.csv'} and {out / 'summary.csv'}")


def _print_summary(
    summary: pd.DataFrame, scores: pd.DataFrame, conventions: str, warnings: list[str]
) -> None:
    """The per-system summary as a table on the terminal, with the warnings above and
    below it and the notes its marks need (oracle, stand-ins, error cells)."""
    from rich.console import Console
    from rich.table import Table

    from skyvln_eval.metrics.aggregate import oracle_systems, unit_of
    from skyvln_eval.reports.paper_tables import (
        ORACLE_NOTE,
        STAND_IN_MARKERS,
        marked_labels,
        oracle_label,
        stand_in_systems,
    )
    from skyvln_eval.reports.tables import ERRORS_MEANING, SOME_ERRORS, cached_calls_note

    title = "scores"
    if warnings:
        incomplete = any(w.startswith("INCOMPLETE") for w in warnings)
        title += (" OF INCOMPLETE RESULTS" if incomplete else "") + " (see the warnings)"
    table = Table(title=title, caption=conventions)
    shown = [m for m in PRINTED_METRICS if m in set(summary.metric)]
    # Two rows of one system and split are told apart by their mode (ANDH, ANDH-Full); a
    # printout of ANDH-Full alone says so too (ANDH is the default task).
    modes = summary["mode"].nunique() > 1 or set(summary["mode"]) == {"andh-full"}
    keys = ("system", "split", *(("mode",) if modes else ()))
    for column in (*keys, "n"):
        table.add_column(column, justify="left" if column in keys else "right")
    for metric in shown:  # with its unit: scores.csv holds shares as fractions, this in %
        unit, header = unit_of(metric), PRINTED_METRICS[metric]
        table.add_column(f"{header}\n({unit})" if unit else header, justify="right")
    oracles = set(oracle_systems(scores))
    stand_ins = stand_in_systems(scores)
    stand_in_labels = marked_labels(stand_ins)
    printed_cells: list[str] = []
    cached: list[str] = []
    for (sys_name, split_name, mode_name), group in summary.groupby(
        ["system", "split", "mode"], sort=True
    ):
        by_metric = group.set_index("metric")
        cells = [_cell(by_metric, m) for m in shown]
        printed_cells += cells
        name = str(sys_name)
        name = oracle_label(name) if name in oracles else stand_in_labels.get(name, name)
        where = (name, str(split_name), *((str(mode_name),) if modes else ()))
        table.add_row(*where, str(int(group.n.max())), *cells)
        share = _cached_share(scores, (sys_name, split_name, mode_name))
        if share is not None:
            in_mode = f" ({mode_name})" if modes else ""
            cached.append(f"{name} on {split_name}{in_mode}: {share:.0f}%")
    console = Console(width=160)
    for warning in warnings:
        console.print(f"WARNING: {warning}", style="bold red", markup=False, highlight=False)
    console.print(table)
    columns = "; ".join(f"{PRINTED_METRICS[m]}: {m}" for m in shown)
    console.print(f"Their columns in scores.csv: {columns}.", markup=False, highlight=False)
    if oracles:
        console.print(ORACLE_NOTE, markup=False, highlight=False)
    for kind in dict.fromkeys(stand_ins[s] for s in stand_in_labels):
        console.print(STAND_IN_MARKERS[kind][1], markup=False, highlight=False)
    if any(cell.endswith(SOME_ERRORS) or cell == "error" for cell in printed_cells):
        console.print(ERRORS_MEANING, markup=False, highlight=False)
    if cached:  # as Table II says it: a cached answer counts the cost of the call that made it
        note = cached_calls_note(cached, "their Cost is that")
        console.print(note, markup=False, highlight=False)
    for warning in warnings:  # again below the table, where the eye lands
        console.print(f"WARNING: {warning}", style="bold red", markup=False, highlight=False)


def _cached_share(scores: pd.DataFrame, row: tuple[Any, Any, Any]) -> float | None:
    """The share (%) of the LLM calls of ``row`` (system, split, mode) answered from the
    response cache, or ``None`` when none was (or the scores do not count calls)."""
    if "llm_cached_calls" not in scores or "llm_calls" not in scores:
        return None
    system, split, mode = (str(value) for value in row)
    episodes = scores[
        (scores["system"].astype(str) == system)
        & (scores["split"].astype(str) == split)
        & (scores["mode"].astype(str) == mode)
    ]
    calls, cached = episodes["llm_calls"].sum(), episodes["llm_cached_calls"].sum()
    return 100.0 * cached / calls if calls > 0 and cached > 0 else None


def _ci_unit(text: str | None) -> CiUnit:
    """``--ci-unit`` checked against the units an interval can resample (None:
    trajectories, the honest default for AVDN's rounds of one dialog)."""
    from skyvln_eval.metrics.aggregate import CI_UNITS, ci_unit_named

    unit = ci_unit_named(text or "trajectory")
    if unit is None:
        raise ConfigError(f"--ci-unit must be one of {', '.join(CI_UNITS)}, not {text!r}")
    return unit


def table(
    scores: Annotated[list[Path], typer.Argument(help="scores.csv files from `skyvln-eval score`")],
    kind: Annotated[
        str,
        typer.Option(help="table1 (systems x splits, SPL/SR) or table2 (LLM backends, SPL/SR/NE)"),
    ] = "table1",
    fmt: Annotated[str, typer.Option("--format", help="md, latex or csv")] = "md",
    row: Annotated[
        list[str] | None, typer.Option(help="Systems to show, in order (repeatable; default all)")
    ] = None,
    mode: Annotated[str, typer.Option(help="Episode mode")] = "andh",
    ci: Annotated[
        bool,
        typer.Option(
            "--ci",
            help="Show 95% confidence intervals (percentile bootstrap, over whole "
            "trajectories by default; for a 0/1 rate, Wilson with the trajectories as "
            "trials widened to the bootstrap's, or Wilson with --ci-unit episode; a note "
            "says which cells used which)",
        ),
    ] = False,
    resamples: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=MAX_BOOTSTRAP_RESAMPLES,
            help="Bootstrap resamples with --ci (default: reproduce's, else 1000)",
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option(
            min=0, max=MAX_BOOTSTRAP_SEED, help="Bootstrap seed (default: reproduce's, else 0)"
        ),
    ] = None,
    digits: Annotated[int, typer.Option(min=0, max=6, help="Decimals")] = 2,
    ci_unit: CiUnitOption = None,
    out: Annotated[Path | None, typer.Option(help="Write here instead of printing")] = None,
) -> None:
    """Render a paper-style table from scores files, as `reproduce` does: systems the
    ground-truth oracle flew (and, in Table II, stand-ins) are references, never ranked.

    Given the scores.csv a reproduction wrote (its tables.json beside it) and no --row,
    the table has that reproduction's rows, order and notes: the file it wrote. Other
    scores show every system, in the order the scores list them."""
    from skyvln_eval.fileio import atomic_write_text
    from skyvln_eval.metrics.scores_io import read_many_scores, scores_warnings
    from skyvln_eval.reports.paper_tables import paper_table
    from skyvln_eval.reports.table_layout import layout_beside
    from skyvln_eval.reports.tables import RENDERERS, TABLES

    if kind not in TABLES:
        raise ConfigError(f"--kind must be one of {sorted(TABLES)}, not {kind!r}")
    if fmt not in RENDERERS:
        raise ConfigError(f"--format must be one of {sorted(RENDERERS)}, not {fmt!r}")
    episode_mode = _mode(mode)
    given = [name for name, value in (("--resamples", resamples), ("--seed", seed),
                                      ("--ci-unit", ci_unit)) if value is not None]  # fmt: skip
    if given and not ci:  # they make the intervals: without them, silently nothing
        raise ConfigError(f"{', '.join(given)} set how --ci intervals are made: add --ci")
    frame, conventions = read_many_scores(scores)
    _check_mode_rows(frame, episode_mode, row)
    layout = layout_beside(scores)
    made = layout.tables.get(kind) if layout is not None else None
    # What scoring warned of (an incomplete run's scores) goes with every table of them.
    warned = [f"WARNING: {w}" for w in scores_warnings(frame)]
    for warning in warned:
        typer.echo(warning, err=True)
    task = [ANDH_FULL_NOTE] if episode_mode == "andh-full" else []
    spec = TABLES[kind]
    if made is not None and made.splits:  # a reproduction's table over other splits
        spec = spec.over(*made.splits)
    shaped = paper_table(
        frame,
        spec,
        conventions,
        rows=row or (list(made.rows) if made is not None else None),
        # The reproduction's notes hold with --row too: what was sensed and how each row
        # ran (a note may name a row not shown).
        notes=[*warned, *task, *(made.notes if made is not None else ())],
        mode=episode_mode,
        digits=digits,
        show_ci=ci,
        resamples=resamples or (layout.resamples if layout is not None else 1000),
        seed=seed if seed is not None else (layout.seed if layout is not None else 0),
        withheld=layout.withheld if layout is not None else (),
        ci_unit=_ci_unit(ci_unit or (layout.ci_unit if layout is not None else None)),
    )
    text = RENDERERS[fmt](shaped)
    if out is None:
        typer.echo(text, nl=False)
    else:
        atomic_write_text(out, text)
        typer.echo(f"wrote {out}")


#: What a table of ANDH-Full episodes says it is over (the task differs from ANDH's).
ANDH_FULL_NOTE = (
    "ANDH-Full: one episode per whole trajectory, flown through all of its dialog rounds "
    "(the toolkit's runs get AVDN's view budget, max_action_len, for each round; AVDN's "
    "code gives the whole dialog one round's)."
)


def _check_mode_rows(frame: Any, mode: str, rows: list[str] | None) -> None:
    """Systems whose scores are all of the other mode: a named one is refused, saying
    --mode; otherwise they are left out of the table with a warning (they were dropped
    without a word)."""
    ours = set(frame.loc[frame["mode"] == mode, "system"].astype(str))
    others = {
        system: sorted(set(group["mode"].astype(str)))
        for system, group in frame[frame["mode"] != mode].groupby("system", sort=True)
        if system not in ours
    }
    if not ours and others:
        modes = sorted({m for found in others.values() for m in found})
        raise ConfigError(
            f"the scores have no {mode!r} episodes, only {listed(modes)}: add --mode {modes[0]}"
        )
    for name in rows or ():
        if name in others:
            raise ConfigError(
                f"system {name!r} has scores of mode {listed(others[name])} only; add "
                f"--mode {others[name][0]}"
            )
    if others and not rows:
        typer.echo(
            f"WARNING: left out: system(s) {listed(list(others))}, whose scores are of "
            f"another mode than {mode!r} (--mode chooses)",
            err=True,
        )


@plot_app.command("control")
def plot_control(
    logs: Annotated[list[Path], typer.Argument(help="Control logs (.parquet or .csv)")],
    out: Annotated[
        Path, typer.Option(help="Folder for control_<case>.<format> (as reproduce names them)")
    ] = Path("figures"),
    fmt: Annotated[str, typer.Option("--format", help="png, pdf or svg")] = "png",
) -> None:
    """Position / attitude vs reference with error curves, one figure per scenario."""
    import pandas as pd

    from skyvln_eval.metrics import read_control_log
    from skyvln_eval.reports.control_figures import control_figure, control_figure_name
    from skyvln_eval.reports.render import save_figure

    log = pd.concat([read_control_log(p) for p in logs], ignore_index=True)
    for scenario in sorted(log["scenario"].unique()):
        figure = control_figure(log, scenario)
        path = save_figure(figure, out / control_figure_name(scenario, fmt))
        typer.echo(f"wrote {path}")


_SPLIT_HELP = (
    "Only this split (repeat for more); by default every split, pooled only when every "
    "system ran the same ones, else one panel per split"
)
_SYSTEM_HELP = "Only this system, as the scores name it (repeat for more, in legend order)"
_MODE_HELP = (
    "Episode mode, andh or andh-full (different tasks, never drawn together); by default "
    "the scores' only one"
)


@plot_app.command("sr-threshold")
def plot_sr_threshold(
    scores: Annotated[list[Path], typer.Argument(help="scores.csv files")],
    out: Annotated[Path, typer.Option(help="Figure file (.png, .pdf, .svg)")] = Path(
        "sr_vs_threshold.png"
    ),
    max_threshold_m: Annotated[float, typer.Option(help="Largest radius shown, metres")] = 100.0,
    split: Annotated[list[str] | None, typer.Option(help=_SPLIT_HELP)] = None,
    system: Annotated[list[str] | None, typer.Option(help=_SYSTEM_HELP)] = None,
    mode: Annotated[str | None, typer.Option(help=_MODE_HELP)] = None,
) -> None:
    """R2R success rate vs success radius, one line per system: one panel pooling the
    splits (its title names them) when every system ran the same ones, else one panel per
    split; error episodes count as failures, as in the tables' SR, and so (under the
    scores' conventions, collision_fails by default) do flights that touched an obstacle;
    the legend counts them, and the degraded ones; oracle runs labelled references."""
    from skyvln_eval.metrics.scores_io import read_many_scores
    from skyvln_eval.reports.nav_figures import sr_vs_threshold_figure
    from skyvln_eval.reports.render import save_figure

    frame, conventions = read_many_scores(scores)
    figure = sr_vs_threshold_figure(
        frame, conventions, system, max_threshold_m, split, _mode(mode) if mode else None
    )
    typer.echo(f"wrote {save_figure(_warned(figure, frame), out)}")


@plot_app.command("ne")
def plot_ne(
    scores: Annotated[list[Path], typer.Argument(help="scores.csv files")],
    out: Annotated[Path, typer.Option(help="Figure file (.png, .pdf, .svg)")] = Path(
        "ne_distribution.png"
    ),
    split: Annotated[list[str] | None, typer.Option(help=_SPLIT_HELP)] = None,
    system: Annotated[list[str] | None, typer.Option(help=_SYSTEM_HELP)] = None,
    mode: Annotated[str | None, typer.Option(help=_MODE_HELP)] = None,
) -> None:
    """Distribution of the navigation error, one histogram per system, in panels as
    `plot sr-threshold` makes them (the title names the splits): error episodes count
    at where they stopped, as in the tables' NE (a system of errors only is named, not
    drawn); the legend counts them, and the degraded ones; oracle runs labelled references."""
    from skyvln_eval.metrics.scores_io import read_many_scores
    from skyvln_eval.reports.nav_figures import ne_distribution_figure
    from skyvln_eval.reports.render import save_figure

    frame, _ = read_many_scores(scores)
    figure = ne_distribution_figure(frame, system, splits=split, mode=_mode(mode) if mode else None)
    typer.echo(f"wrote {save_figure(_warned(figure, frame), out)}")


def _warned(figure: Any, frame: Any) -> Any:
    """``figure`` marked, and each warning of its scores said on stderr: what scoring
    warned of (an incomplete run's scores, a coverage not checked) goes with every figure
    of them, as with every table."""
    from skyvln_eval.metrics.scores_io import scores_warnings

    warnings = scores_warnings(frame)
    for warning in warnings:
        typer.echo(f"WARNING: {warning}", err=True)
    if warnings:
        first = warnings[0].split(":")[0]  # e.g. INCOMPLETE, NOT CHECKED whether ...
        figure.suptitle(
            f"WARNING ({len(warnings)}): {first[:60]}... (see the scores file)",
            color="tab:red",
            fontsize="small",
        )
    return figure


def _data_dir(value: str) -> Path:
    """``--data-dir``: ``sample`` / ``full`` as a run config's ``data:``, else a folder."""
    from skyvln_eval.cli import data_dir_argument  # here: the CLI imports this module

    return data_dir_argument(value)


#: How many of a file's episode ids an error names when the one asked for is not there.
_IDS_SHOWN = 5


def _trajectory_row(
    path: Path, rows: Sequence[EpisodeResult], episode: str, system: str | None
) -> EpisodeResult:
    """The one row of ``episode`` (of ``system``, if given) in the results ``path``; else
    an error that says what the file has: the episode's systems, or some of its ids."""
    of_episode = [r for r in rows if r.episode_id == episode]
    if not of_episode:
        ids = sorted({r.episode_id for r in rows})
        shown = ", ".join(ids[:_IDS_SHOWN]) + (", ..." if len(ids) > _IDS_SHOWN else "")
        raise ConfigError(f"{path}: no episode {episode!r} in it ({len(ids)} episode(s): {shown})")
    systems = sorted({r.system for r in of_episode})
    chosen = [r for r in of_episode if system is None or r.system == system]
    if not chosen:
        raise ConfigError(
            f"{path}: episode {episode!r} has no row of system {system!r}; its system(s): "
            f"{', '.join(map(repr, systems))} (--system)"
        )
    if len(chosen) == 1:
        return chosen[0]
    if system is None and len(systems) > 1:
        raise ConfigError(
            f"{path}: {len(chosen)} rows for episode {episode!r}, of systems "
            f"{', '.join(map(repr, systems))}; choose one with --system"
        )
    # One system, several rows: the same episode in several splits or modes.
    where = ", ".join(sorted(f"{r.split}/{r.mode}" for r in chosen))
    raise ConfigError(
        f"{path}: {len(chosen)} rows for episode {episode!r} of system {chosen[0].system!r} "
        f"(split/mode {where}); give a results file holding one of them"
    )


@plot_app.command("trajectory")
def plot_trajectory(
    results: Annotated[
        Path, typer.Argument(help="A run directory or its result rows (.jsonl or .parquet)")
    ],
    episode: Annotated[str, typer.Option(help="Episode id, e.g. 1913__3_1")],
    data_dir_text: Annotated[
        str,
        typer.Option(
            "--data-dir", help="The dataset the episode comes from, for its map (or sample / full)"
        ),
    ],
    system: Annotated[str | None, typer.Option(help="Which system's row, if several")] = None,
    out: Annotated[Path, typer.Option(help="Figure file (.png, .pdf, .svg)")] = Path(
        "trajectory.png"
    ),
) -> None:
    """An episode's GT and flown views drawn over its map tile; the title says an episode's
    status unless ok (an error episode's with its first error line)."""
    from skyvln_eval.avdn import load_split
    from skyvln_eval.harness.store import RESULTS_FILE
    from skyvln_eval.metrics import read_results
    from skyvln_eval.reports.render import save_figure
    from skyvln_eval.reports.trajectory_figure import trajectory_figure, trajectory_labels
    from skyvln_eval.worlds import load_world

    # One episode's figure: the episodes an unfinished run has are drawn. A run directory
    # is read by its rows (as score and view take it; it was refused as "a directory").
    if results.is_dir() and (results / RESULTS_FILE).is_file():
        results = results / RESULTS_FILE
    row = _trajectory_row(results, read_results(results, allow_incomplete=True), episode, system)
    data_dir = _data_dir(data_dir_text)
    records = [r for r in load_split(data_dir, row.split).records if r.episode_id == episode]
    if not records:
        raise ConfigError(f"{data_dir}: split {row.split} has no episode {episode!r}")
    tile = load_world(data_dir, records[0].map_name, records[0].georef)
    title, flown = trajectory_labels(row)  # an error episode's title says so
    figure = trajectory_figure(
        tile, row.gt_path_corners, row.visited_views, title, agent_label=flown
    )
    typer.echo(f"wrote {save_figure(figure, out)}")
