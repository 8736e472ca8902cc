"""The score, table and plot commands end to end on small files."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.errors import IncompleteRunError, NoGroundTruthError
from skyvln_eval.metrics import RESULTS_VERSION, Prediction, write_predictions_json, write_results
from skyvln_eval.metrics.scores_io import read_scores
from tests.conftest import CliOutcome, make_record
from tests.metrics.helpers import result, square
from tests.reports.test_figures import two_controller_log

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
    ]
    for (kind, path), needle in cases:
        outcome = cli("plot", kind, str(path), "--out", str(tmp_path / "figure.png"))
        assert outcome.code == 2, (kind, path, outcome)
        assert "Traceback" not in outcome.err and needle in outcome.err, (needle, outcome.err)
        if kind == "control":
            assert "RUN_DIR/control/<split>/<episode_id>.parquet" in outcome.err
    assert not (tmp_path / "figure.png").exists()
