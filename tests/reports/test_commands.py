"""The score, table and plot commands end to end on small files."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner

from skyvln_eval.avdn import load_split
from skyvln_eval.cli import app
from skyvln_eval.errors import (
    DataError,
    IncompleteRunError,
    NoGroundTruthError,
    ResultRecordError,
)
from skyvln_eval.metrics import (
    RESULTS_VERSION,
    Prediction,
    read_results,
    write_predictions_json,
    write_results,
)
from skyvln_eval.metrics.scores_io import read_scores
from skyvln_eval.reports import render
from tests.conftest import CliOutcome, make_record, write_dataset
from tests.metrics.helpers import result, square
from tests.reports.test_figures import two_controller_log

if TYPE_CHECKING:
    from matplotlib.figure import Figure

runner = CliRunner()
Cli = Callable[..., CliOutcome]


def write_run(path: Path) -> Path:
    g = [square(0, 0), square(100, 0)]
    rows = []
    for split in ("val_seen", "val_unseen", "test_unseen"):
        for k in range(6):
            rows.append(
                result(
                    [g[0], square(100, 3 * k)],
                    g,
                    episode_id=f"m__{k}_1",
                    split=split,
                    system="Ours Full",
                )
            )
            rows.append(
                result(
                    [g[0], square(60, 5 * k)],
                    g,
                    episode_id=f"m__{k}_1",
                    split=split,
                    system="w/o HSD",
                )
            )
    write_results(path, rows)
    return path


def test_score_then_table_then_plots(tmp_path: Path) -> None:
    run = write_run(tmp_path / "run.jsonl")
    out = tmp_path / "scores"
    scored = runner.invoke(
        app, ["score", str(run), "--out", str(out), "--threshold-m", "10", "--distance", "3d"]
    )
    assert scored.exit_code == 0, scored.output
    assert "Ours Full" in scored.output and "success NE < 10 m" in scored.output
    scores, conventions = read_scores(out / "scores.csv")
    assert conventions.threshold_m == 10.0 and conventions.distance == "3d"
    assert len(scores) == 36
    assert (out / "summary.csv").read_text().startswith("# conventions: {")

    latex = runner.invoke(
        app, ["table", str(out / "scores.csv"), "--format", "latex", "--ci", "--resamples", "200"]
    )
    assert latex.exit_code == 0, latex.output
    assert r"\multicolumn{2}{c}{\textbf{Unseen Testing}}" in latex.output
    assert r"\scriptsize[" in latex.output and '"threshold_m":10.0' in latex.output
    # Which resamples and seed made the bootstrap bounds (score's may have used others).
    assert (
        "percentile bootstrap of the trajectories (the rounds of a dialog drawn together), "
        "200 resamples, seed 0: " in latex.output
    )
    md_path = tmp_path / "t2.md"
    rows = ["--row", "w/o HSD", "--row", "Ours Full"]
    md = runner.invoke(
        app, ["table", str(out / "scores.csv"), "--kind", "table2", "--out", str(md_path), *rows]
    )
    assert md.exit_code == 0, md.output
    text = md_path.read_text()
    assert text.index("| w/o HSD") < text.index("| Ours Full")

    for kind, target in (("sr-threshold", "sr.png"), ("ne", "ne.svg")):
        plotted = runner.invoke(
            app, ["plot", kind, str(out / "scores.csv"), "--out", str(tmp_path / target)]
        )
        assert plotted.exit_code == 0, plotted.output
        assert (tmp_path / target).stat().st_size > 0
        # --split and --system choose what is drawn (repeatable); a name that has no
        # scores is refused, naming those there are.
        chosen = ["--split", "val_seen", "--split", "test_unseen", "--system", "w/o HSD"]
        target = tmp_path / f"chosen_{target}"
        plotted = runner.invoke(
            app, ["plot", kind, str(out / "scores.csv"), "--out", str(target), *chosen]
        )
        assert plotted.exit_code == 0, plotted.output
        assert target.stat().st_size > 0
        refused = runner.invoke(
            app, ["plot", kind, str(out / "scores.csv"), "--out", str(target), "--system", "Full"]
        )
        assert refused.exit_code != 0
        assert "the scores have the systems 'Ours Full', 'w/o HSD'" in str(refused.exception)

    log_path = tmp_path / "log.parquet"
    two_controller_log().to_parquet(log_path)
    plotted = runner.invoke(
        app, ["plot", "control", str(log_path), "--out", str(tmp_path / "fig"), "--format", "pdf"]
    )
    assert plotted.exit_code == 0, plotted.output
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == [
        "control_dynamic.pdf",
        "control_static.pdf",
    ]


def test_scoring_predictions_against_a_dataset(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    records = [make_record(route_index="0_1"), make_record(route_index="1_1", heading=90.0)]
    root = dataset_factory({"val_seen": records, "test_unseen": [make_record(n_views=1)]})
    gt = {f"1913__{r['route_index']}": np.array(r["gt_path_corners"]) for r in records}
    predictions = {eid: Prediction(eid, views) for eid, views in gt.items()}
    path = tmp_path / "preds.json"
    write_predictions_json(path, predictions)
    out = tmp_path / "s"
    ok = runner.invoke(
        app,
        [
            "score",
            str(path),
            "--data-dir",
            str(root),
            "--split",
            "val_seen",
            "--out",
            str(out),
            "--system",
            "oracle",
        ],
    )
    assert ok.exit_code == 0, ok.output
    scores, _ = read_scores(out / "scores.csv")
    assert scores.success.tolist() == [1.0, 1.0] and set(scores.system) == {"oracle"}

    del predictions["1913__1_1"]
    write_predictions_json(path, predictions)
    missing = runner.invoke(
        app, ["score", str(path), "--data-dir", str(root), "--split", "val_seen"]
    )
    # main() turns SkyvlnError into exit status 2; the test runner sees the exception itself.
    assert isinstance(missing.exception, IncompleteRunError)
    assert "1 missing episode(s): 1913__1_1" in str(missing.exception)

    withheld = runner.invoke(
        app, ["score", str(path), "--data-dir", str(root), "--split", "test_unseen"]
    )
    assert isinstance(withheld.exception, NoGroundTruthError)
    assert "has no ground truth" in str(withheld.exception)


def test_score_refuses_an_incomplete_run(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    root = dataset_factory(
        {"val_seen": [make_record(route_index="0_1"), make_record(route_index="7_1")]}
    )
    views = np.array(make_record()["gt_path_corners"])
    run = tmp_path / "run.jsonl"
    write_results(run, [result(views, views, episode_id="1913__0_1")])
    failed = runner.invoke(
        app, ["score", str(run), "--data-dir", str(root), "--out", str(tmp_path / "o")]
    )
    assert isinstance(failed.exception, IncompleteRunError)
    expected = "run agent/val_seen/andh is incomplete: 1 missing episode(s): 1913__7_1"
    assert expected in str(failed.exception)
    assert not (tmp_path / "o" / "scores.csv").exists()  # nothing written for a partial run
    assert json.loads(run.read_text().splitlines()[0])["version"] == RESULTS_VERSION


def test_table_refuses_an_episode_given_twice(tmp_path: Path) -> None:
    """Two scores files (or one file twice) holding an episode of the same system, split
    and mode would be averaged as one row: refused, naming both files and rows."""
    g = [square(0, 0), square(100, 0)]
    short = [result([g[0], square(100, 0)], g, episode_id=f"m__{k}_1") for k in range(3)]
    long = [result([g[0], square(100, 9 * k)], g, episode_id=f"m__{k}_1") for k in range(8)]
    paths = []
    for name, rows in (("short", short), ("long", long)):
        write_results(tmp_path / f"{name}.jsonl", rows)
        scored = runner.invoke(
            app, ["score", str(tmp_path / f"{name}.jsonl"), "--out", str(tmp_path / name)]
        )
        assert scored.exit_code == 0, scored.output
        paths.append(str(tmp_path / name / "scores.csv"))

    twice = runner.invoke(app, ["table", paths[0], paths[0], "--ci"])
    assert isinstance(twice.exception, ResultRecordError)
    assert str(twice.exception).startswith(f"{paths[0]}, record 0 (episode m__0_1)")
    # Line 5: the format, the conventions, a warning (scored without --data-dir: coverage
    # not checked), the CSV header, then the first row.
    assert "# warning: NOT CHECKED whether" in Path(paths[0]).read_text()
    assert f"duplicates record 0 of {paths[0]} (line 5)" in str(twice.exception)

    merged = runner.invoke(app, ["table", paths[0], paths[1]])
    assert isinstance(merged.exception, ResultRecordError)
    message = str(merged.exception)
    assert message.startswith(f"{paths[1]}, record 0 (episode m__0_1), field 'episode_id'")
    assert f"record 0 of {paths[0]} (line 5)" in message and "same system 'agent'" in message
    assert "different system labels" in message

    # One file holding an episode twice (e.g. two files pasted together) is refused on reading.
    lines = Path(paths[1]).read_text().splitlines(keepends=True)
    Path(paths[1]).write_text("".join([*lines, lines[6]]))
    pasted = runner.invoke(app, ["table", paths[1]])
    assert isinstance(pasted.exception, ResultRecordError)
    assert "line 13 duplicates record 2 of this file (line 7)" in str(pasted.exception)


def test_score_takes_a_run_directory_and_names_what_it_cannot_score(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_run(run_dir / "results.jsonl")
    out = tmp_path / "scores"
    scored = runner.invoke(app, ["score", str(run_dir), "--out", str(out)])
    assert scored.exit_code == 0, scored.output
    assert len(read_scores(out / "scores.csv")[0]) == 36

    (run_dir / "run.json").write_text('{"system": "Ours Full", "expected": 18}')
    report = runner.invoke(app, ["score", str(run_dir / "run.json")])
    assert isinstance(report.exception, DataError)
    assert str(report.exception) == (
        f"{run_dir / 'run.json'}: the report of a run (episodes by status, errors), not its "
        f"results; score the run directory {run_dir} (or {run_dir / 'results.jsonl'})"
    )
    empty = runner.invoke(app, ["score", str(tmp_path / "scores")])
    assert isinstance(empty.exception, DataError)
    assert "a directory without results.jsonl, here or below" in str(empty.exception)
    absent = runner.invoke(app, ["score", str(tmp_path / "preds.npy")])
    assert str(absent.exception) == f"{tmp_path / 'preds.npy'}: no such file or directory"

    # The same rows in two files: the error names both files (not '<results>').
    copy = tmp_path / "copy.jsonl"
    copy.write_bytes((run_dir / "results.jsonl").read_bytes())
    twice = runner.invoke(app, ["score", str(run_dir), str(copy)])
    assert isinstance(twice.exception, ResultRecordError)
    message = str(twice.exception)
    assert message.startswith(f"{copy}, record 0 (episode m__0_1), field 'episode_id'")
    assert f"duplicate of record 0 of {run_dir / 'results.jsonl'}" in message
    assert "different system labels" in message


def test_plots_of_the_wrong_file_say_what_it_should_be(tmp_path: Path, cli: Cli) -> None:
    run = write_run(tmp_path / "run.jsonl")
    scores = tmp_path / "scores" / "scores.csv"
    assert cli("score", str(run), "--out", str(scores.parent), "--resamples", "0").code == 0
    log = tmp_path / "log.parquet"
    two_controller_log().to_parquet(log)
    binary_csv = tmp_path / "image.csv"
    binary_csv.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    (tmp_path / "empty.csv").write_text("")
    torn = tmp_path / "torn.csv"
    torn.write_text("\n".join(scores.read_text().split("\n")[:3]) + '\n"unclosed\n')
    results = tmp_path / "results.parquet"
    write_results(results, [result([square(0, 0)], [square(0, 0)])])
    cases = [
        (("control", scores), f"{scores}: not a control log (not CSV: Error tokenizing data"),
        (("control", binary_csv), f"{binary_csv}: not a control log (not CSV: 'utf-8' codec"),
        (("control", tmp_path / "empty.csv"), "not a control log (not CSV: No columns to parse"),
        (("control", results), f"{results}: not a control log (its columns: episode_id, "),
        (("sr-threshold", log), f"{log}: not a scores file (not UTF-8 text)"),
        (("ne", binary_csv), f"{binary_csv}: not a scores file (not UTF-8 text)"),
        (("ne", torn), f"{torn}: the scores table is not valid CSV (Error tokenizing data"),
        # Folders (an audit: "scores file not found", "control log not found" for them).
        (("ne", scores.parent), f"{scores.parent}: a folder; its scores are {scores}"),
        (("ne", tmp_path), f"{tmp_path}: a folder, not a scores file (a run directory? score"),
        (("control", tmp_path), f"{tmp_path}: a folder, not a control log"),
    ]
    for (kind, path), needle in cases:
        outcome = cli("plot", kind, str(path), "--out", str(tmp_path / "figure.png"))
        assert outcome.code == 2, (kind, path, outcome)
        assert "Traceback" not in outcome.err and needle in outcome.err, (needle, outcome.err)
        if kind == "control":
            assert "RUN_DIR/control/<split>/<episode_id>.parquet" in outcome.err
    assert not (tmp_path / "figure.png").exists()


def test_predictions_start_at_the_start_view_and_may_be_scored_incomplete_when_allowed(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    records = [make_record(route_index="0_1"), make_record(route_index="1_1", heading=90.0)]
    root = dataset_factory({"val_seen": records})
    gt = {f"1913__{r['route_index']}": np.array(r["gt_path_corners"]) for r in records}
    path = tmp_path / "preds.json"
    args = ["--data-dir", str(root), "--split", "val_seen", "--out", str(tmp_path / "s")]
    # The start view left out: a shorter path, a higher SPL. Refused, naming the episode.
    write_predictions_json(path, {eid: Prediction(eid, views[1:]) for eid, views in gt.items()})
    cut = runner.invoke(app, ["score", str(path), *args])
    assert isinstance(cut.exception, DataError)
    assert "episode 1913__0_1: the path does not begin with the episode's start view" in str(
        cut.exception
    )
    # One episode predicted: refused, unless --allow-incomplete, which says so and scores it.
    write_predictions_json(path, {"1913__0_1": Prediction("1913__0_1", gt["1913__0_1"])})
    assert isinstance(runner.invoke(app, ["score", str(path), *args]).exception, IncompleteRunError)
    allowed = runner.invoke(app, ["score", str(path), *args, "--allow-incomplete"])
    assert allowed.exit_code == 0, allowed.output
    said = " ".join(allowed.output.split())
    assert "1 missing episode(s): 1913__1_1" in said
    assert said.count("WARNING:") == 2  # one warning, above and below the table
    assert len(read_scores(tmp_path / "s" / "scores.csv")[0]) == 1


def test_plot_trajectory_says_which_systems_have_the_episode_or_that_it_is_not_there(
    tmp_path: Path, cli: Cli
) -> None:
    run = write_run(tmp_path / "run.jsonl")  # m__0_1 .. m__5_1 of 'Ours Full' and 'w/o HSD'
    one_split = tmp_path / "one_split.jsonl"
    write_results(one_split, [r for r in read_results(run) if r.split == "val_seen"])

    def trajectory(path: Path, *args: str) -> str:
        outcome = cli("plot", "trajectory", str(path), "--data-dir", str(tmp_path), *args)
        assert outcome.code == 2 and "Traceback" not in outcome.err, outcome
        return " ".join(outcome.err.split())

    systems = "its system(s): 'Ours Full', 'w/o HSD'"
    assert f"{one_split}: episode 'm__2_1' has no row of system 'Ours'; {systems}" in (
        trajectory(one_split, "--episode", "m__2_1", "--system", "Ours")
    )
    assert (
        "no episode 'm__9_1' in it (6 episode(s): m__0_1, m__1_1, m__2_1, m__3_1, m__4_1, ...)"
        in (trajectory(one_split, "--episode", "m__9_1", "--system", "Ours Full"))
    )
    assert (
        "2 rows for episode 'm__2_1', of systems 'Ours Full', 'w/o HSD'; choose one with --system"
        in (trajectory(one_split, "--episode", "m__2_1"))
    )
    assert "(split/mode test_unseen/andh, val_seen/andh, val_unseen/andh)" in (
        trajectory(run, "--episode", "m__2_1", "--system", "w/o HSD")
    )
    assert not (tmp_path / "trajectory.png").exists()


def test_plot_trajectory_of_an_error_episode_is_titled_with_its_error(
    tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Ratios that fit the fixture's 100 px map image (the defaults are for a 1000 px one).
    record = make_record(lng_ratio=1e-4, lat_ratio=1e-4)
    data_dir = write_dataset(tmp_path / "ds", {"val_seen": [record]})
    (record,) = load_split(data_dir, "val_seen").records
    gt = record.gt_path_corners
    failed = result(gt[:2], gt, status="error", error="TimeoutError: no answer\nTraceback ...")
    results = tmp_path / "run" / "results.jsonl"  # given by its run directory, as score takes it
    results.parent.mkdir()
    write_results(results, [failed])
    drawn: list[Figure] = []
    monkeypatch.setattr(render, "save_figure", lambda figure, path: drawn.append(figure) or path)
    outcome = cli(
        "plot", "trajectory", str(results.parent), "--episode", failed.episode_id,
        "--data-dir", str(data_dir), "--out", str(tmp_path / "t.png"),
    )  # fmt: skip
    assert outcome.code == 0, outcome
    (ax,) = drawn[0].get_axes()
    assert ax.get_title() == "agent: 1913__0_1 — error: TimeoutError: no answer"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "agent, until the error" in legend


@pytest.mark.parametrize(
    ("command", "says"),
    [
        ("sr-threshold", ["error episodes count as failures", "touched an obstacle"]),
        ("ne", ["error episodes count at where they stopped"]),
    ],
)
def test_the_plot_help_says_how_error_episodes_are_drawn(command: str, says: list[str]) -> None:
    # The figures once left error episodes out; the help said so after they stopped doing it.
    shown = CliRunner().invoke(app, ["plot", command, "--help"], env={"COLUMNS": "200"})
    assert shown.exit_code == 0, shown.output
    text = " ".join(shown.output.replace("│", " ").split())
    assert all(phrase in text for phrase in says), text
    assert "left out" not in text


def test_tables_and_the_score_printout_keep_the_two_modes_apart(tmp_path: Path) -> None:
    """An audit: table dropped the systems of the other mode without a word (and --row
    denied they existed), score printed two rows of one system and split alike, and
    --seed or --ci-unit without --ci did nothing."""
    g = [square(0, 0), square(100, 0)]
    rows = [
        result([g[0], square(100, 3 * k)], g, episode_id=f"m__{k}_1", split=split,
               system=system, mode=mode)
        for system, mode in (("A", "andh"), ("A", "andh-full"), ("F", "andh-full"))
        for split in ("val_seen", "val_unseen", "test_unseen")
        for k in range(3)
    ]  # fmt: skip
    write_results(tmp_path / "run.jsonl", rows)
    out = tmp_path / "scores"
    scored = runner.invoke(app, ["score", str(tmp_path / "run.jsonl"), "--out", str(out)])
    assert scored.exit_code == 0, scored.output
    header = next(line for line in scored.output.splitlines() if " system " in line)
    assert header.split()[1:7:2] == ["system", "split", "mode"]  # between the box rules
    # Metrics under short headers, whole (scores.csv's names were cut: "oracle_succe…"),
    # and the note says which column each is.
    names = next(line for line in scored.output.splitlines() if " SR " in line).split()
    assert [n for n in names if n not in "┃"][:6] == ["SR", "OSR", "SPL", "GP", "NE", "TL"]
    assert "…" not in scored.output.split("Their columns")[0]
    assert "SR: success; OSR: oracle_success; SPL: spl;" in " ".join(scored.output.split())
    assert sum(" andh-full " in line for line in scored.output.splitlines()) == 6
    scores = str(out / "scores.csv")
    shown = runner.invoke(app, ["table", scores])
    assert shown.exit_code == 0, shown.output
    assert "WARNING: left out: system(s) 'F', whose scores are of another mode" in shown.output
    assert "| F " not in shown.output and "ANDH-Full" not in shown.output
    named = runner.invoke(app, ["table", scores, "--row", "F"])
    assert named.exit_code != 0
    told = "system 'F' has scores of mode 'andh-full' only; add --mode andh-full"
    assert told in str(named.exception)
    full = runner.invoke(app, ["table", scores, "--mode", "andh-full", "--row", "F"])
    assert full.exit_code == 0, full.output
    assert "| F " in full.output and "ANDH-Full: one episode per whole trajectory" in full.output
    f_only = tmp_path / "f_only"
    write_results(tmp_path / "f.jsonl", [r for r in rows if r.system == "F"])
    f_scored = runner.invoke(app, ["score", str(tmp_path / "f.jsonl"), "--out", str(f_only)])
    assert f_scored.exit_code == 0, f_scored.output
    # ANDH-Full alone says so (nothing did), and shares say they are in % (scores.csv
    # holds them as fractions).
    assert sum(" andh-full " in line for line in f_scored.output.splitlines()) == 3
    assert "(%)" in f_scored.output and "(m)" in f_scored.output
    alone = runner.invoke(app, ["table", str(f_only / "scores.csv")])
    assert "no 'andh' episodes, only 'andh-full': add --mode andh-full" in str(alone.exception)
    for option in (["--seed", "5"], ["--ci-unit", "trajectory"], ["--resamples", "7"]):
        refused = runner.invoke(app, ["table", scores, *option])
        assert refused.exit_code != 0
        told = f"{option[0]} set how --ci intervals are made: add --ci"
        assert told in str(refused.exception)


@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [
        ("--seed", "-1", "greater than or equal to 0"),
        ("--seed", "99999999999999999999999", "less than or equal to"),
        ("--resamples", "99999999999999999999999", "less than or equal to"),
    ],
)
def test_a_bootstrap_seed_or_resamples_numpy_cannot_take_is_refused_before_scoring(
    tmp_path: Path, cli: Cli, option: str, value: str, needle: str
) -> None:
    # An audit: each was a traceback (exit 1) from numpy or pandas after the scoring.
    run = write_run(tmp_path / "run.jsonl")
    out = tmp_path / "scores"
    scored = cli("score", str(run), "--out", str(out), option, value)
    assert scored.code == 2 and "Traceback" not in scored.err, scored
    assert option in scored.err and needle in scored.err
    assert not out.exists()
    assert cli("score", str(run), "--out", str(out), "--resamples", "0").code == 0
    tabled = cli("table", str(out / "scores.csv"), "--ci", option, value)
    assert tabled.code == 2 and "Traceback" not in tabled.err, tabled


def test_an_out_of_the_wrong_kind_is_named_before_any_work(tmp_path: Path, cli: Cli) -> None:
    # An audit: "afile: File exists (EEXIST)" after the scoring, and a table written over a
    # folder named a temporary file (".tiny.rqhbu2h7.tmp: Is a directory").
    run = write_run(tmp_path / "run.jsonl")
    afile = tmp_path / "afile"
    afile.write_text("mine")
    scored = cli("score", str(run), "--out", str(afile))
    assert scored.code == 2 and f"--out {afile} is an existing file, not a folder" in scored.err
    assert afile.read_text() == "mine"
    assert cli("score", str(run), "--out", str(tmp_path / "scores"), "--resamples", "0").code == 0
    tabled = cli("table", str(tmp_path / "scores" / "scores.csv"), "--out", str(tmp_path))
    assert tabled.code == 2 and f"{tmp_path}: a folder, not a file: name a file" in tabled.err
    assert not list(tmp_path.glob(".*.tmp"))
