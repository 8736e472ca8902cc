"""`score` on a run directory: the run's rows must cover the episodes its config selects."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from skyvln_eval.avdn import load_split
from skyvln_eval.cli import app
from skyvln_eval.errors import DataError, IncompleteRunError
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.run import episode_logs
from skyvln_eval.metrics import read_results, write_results
from skyvln_eval.metrics.scores_io import read_scores
from skyvln_eval.reports.run_coverage import selected_episodes
from tests.conftest import make_record
from tests.metrics.helpers import result

runner = CliRunner()
IDS = ["1913__0_1", "1913__1_1", "1913__2_1", "1913__3_1"]


def config(data: Path, **overrides: Any) -> RunConfig:
    settings: dict[str, Any] = {"system": "agent", "data": str(data), "splits": ("val_seen",)}
    return RunConfig.model_validate(settings | overrides)


@pytest.fixture
def dataset(dataset_factory: Callable[..., Path]) -> Path:
    """Four val_seen episodes, in the file order of IDS."""
    return dataset_factory({"val_seen": [make_record(route_index=e[6:]) for e in IDS]})


def run_dir(path: Path, run_config: RunConfig, ids: list[str], **extra: Any) -> Path:
    """A run directory as the harness leaves it, with rows for ``ids`` only."""
    path.mkdir()
    (path / "config.yaml").write_text(run_config.to_yaml())
    views = np.array(make_record()["gt_path_corners"])
    rows = [result(views, views, episode_id=e, extra=extra.get(e, {})) for e in ids]
    write_results(path / "results.jsonl", rows)
    return path


def score(*args: str | Path) -> Any:
    return runner.invoke(app, ["score", *map(str, args)])


def test_an_interrupted_run_is_refused_unless_allowed(dataset: Path, tmp_path: Path) -> None:
    run_path = run_dir(tmp_path / "run", config(dataset, limit=3), IDS[:1])
    out = tmp_path / "scores"
    refused = score(run_path / "results.jsonl", "--out", out)
    assert isinstance(refused.exception, IncompleteRunError)
    assert str(refused.exception) == (
        f"run {run_path} (system 'agent': 3 episode(s) selected by its config.yaml, 1 recorded) "
        "is incomplete: 2 missing episode(s): val_seen/1913__1_1, val_seen/1913__2_1. Finish "
        f"it with `skyvln-eval run {run_path / 'config.yaml'} --out {run_path}`, which runs "
        "only the missing episodes, or pass --allow-incomplete (in Python, "
        "allow_incomplete=True) to score the 1 recorded episode(s) as they are"
    )
    assert not out.exists()  # nothing written for a partial run

    allowed = score(run_path, "--out", out, "--allow-incomplete")
    assert allowed.exit_code == 0, allowed.output
    text = " ".join(allowed.output.split())  # Rich wraps long lines
    assert text.count("WARNING: INCOMPLETE: run") == 2  # above and below the table
    assert "2 episode(s) missing (val_seen/1913__1_1, val_seen/1913__2_1)" in text
    assert "scores OF INCOMPLETE RESULTS" in text
    assert "# warning: INCOMPLETE: run" in (out / "summary.csv").read_text()
    assert read_scores(out / "scores.csv")[0].episode_id.tolist() == IDS[:1]
    # The scores file says so too, and every table made from it (an audit found a clean
    # table of 1 of 15 episodes, SR 100%).
    assert "# warning: INCOMPLETE: run" in (out / "scores.csv").read_text()
    table = runner.invoke(app, ["table", str(out / "scores.csv")])
    assert table.exit_code == 0, table.output
    assert "WARNING: INCOMPLETE: run" in table.stdout.split("| agent |")[1]  # a table note
    for kind in ("sr-threshold", "ne"):  # and every figure of them
        png = out / f"{kind}.png"
        plotted = runner.invoke(app, ["plot", kind, str(out / "scores.csv"), "--out", str(png)])
        assert plotted.exit_code == 0 and png.is_file(), plotted.output
        assert "WARNING: INCOMPLETE: run" in plotted.stderr


def test_a_limited_run_is_complete_with_or_without_data_dir(dataset: Path, tmp_path: Path) -> None:
    run_path = run_dir(tmp_path / "run", config(dataset, limit=2), IDS[:2])
    plain = score(run_path, "--out", tmp_path / "a")
    assert plain.exit_code == 0, plain.output
    assert "WARNING" not in plain.output
    # --data-dir checks the run's selection (2 episodes), not the whole split (4).
    checked = score(run_path, "--data-dir", dataset, "--out", tmp_path / "b")
    assert checked.exit_code == 0, checked.output

    # A copy of the rows outside the run directory is checked against the whole split.
    copy = tmp_path / "copy.jsonl"
    copy.write_bytes((run_path / "results.jsonl").read_bytes())
    whole = score(copy, "--data-dir", dataset, "--out", tmp_path / "c")
    assert isinstance(whole.exception, IncompleteRunError)
    assert "2 missing episode(s): 1913__2_1, 1913__3_1" in str(whole.exception)
    allowed = score(copy, "--data-dir", dataset, "--out", tmp_path / "c", "--allow-incomplete")
    assert allowed.exit_code == 0, allowed.output
    assert "WARNING: INCOMPLETE: run agent/val_seen/andh is incomplete" in allowed.output


def test_rows_outside_the_selection_and_stopping_rows(dataset: Path, tmp_path: Path) -> None:
    chosen = config(dataset, episodes=[IDS[3], IDS[1]])
    extra = run_dir(tmp_path / "extra", chosen, [IDS[1], IDS[3], IDS[0]])
    refused = score(extra, "--allow-incomplete", "--out", tmp_path / "o")
    assert isinstance(refused.exception, IncompleteRunError)  # never allowed
    assert (
        f"1 episode(s) not in the run's selection from {dataset}: val_seen/1913__0_1. Is "
        f"{dataset} the dataset the run ran on?" in str(refused.exception)
    )

    # A row that only records the run stopping (refused credentials) is no result: its
    # episode runs again, so it is missing, and left out when scoring anyway.
    fatal = {IDS[3]: {"fatal": "refused credentials"}}
    stopped = run_dir(tmp_path / "stopped", chosen, [IDS[1], IDS[3]], **fatal)
    refused = score(stopped, "--out", tmp_path / "o")
    assert isinstance(refused.exception, IncompleteRunError)
    assert "1 missing episode(s): val_seen/1913__3_1" in str(refused.exception)
    assert "1 of the missing have a row that only records the run stopping" in str(
        refused.exception
    )
    allowed = score(stopped, "--allow-incomplete", "--out", tmp_path / "o")
    assert allowed.exit_code == 0, allowed.output
    assert read_scores(tmp_path / "o" / "scores.csv")[0].episode_id.tolist() == [IDS[1]]

    # Copied out of its run directory, the stop row is still no episode's result (it was
    # scored as an 'error' episode).
    copy = tmp_path / "copy.jsonl"
    copy.write_bytes((stopped / "results.jsonl").read_bytes())
    refused = score(copy, "--out", tmp_path / "p")
    assert isinstance(refused.exception, IncompleteRunError)
    assert "1 row(s) only record that the run stopped there (refused credentials)" in str(
        refused.exception
    )
    allowed = score(copy, "--allow-incomplete", "--out", tmp_path / "p")
    assert allowed.exit_code == 0, allowed.output
    assert "1 row(s) only record the run stopping there and are left out" in " ".join(
        allowed.output.split()
    )
    assert read_scores(tmp_path / "p" / "scores.csv")[0].episode_id.tolist() == [IDS[1]]


def test_a_run_whose_episodes_cannot_be_known(dataset: Path, tmp_path: Path) -> None:
    gone = run_dir(tmp_path / "gone", config(tmp_path / "moved", limit=2), IDS[:2])
    refused = score(gone, "--out", tmp_path / "o")
    assert isinstance(refused.exception, DataError)
    assert f"the data of run {gone} ('{tmp_path / 'moved'}') is not at" in str(refused.exception)
    assert score(gone, "--data-dir", dataset, "--out", tmp_path / "o").exit_code == 0
    unchecked = score(gone, "--allow-incomplete", "--out", tmp_path / "o")
    assert unchecked.exit_code == 0, unchecked.output
    assert f"WARNING: NOT CHECKED whether {gone / 'results.jsonl'} is complete" in " ".join(
        unchecked.output.split()
    )

    (gone / "config.yaml").unlink()
    (gone / "run.json").write_text("{}")
    no_config = score(gone, "--out", tmp_path / "o")
    assert isinstance(no_config.exception, DataError)
    assert "has a run report (run.json) but no config.yaml" in str(no_config.exception)


def test_the_selection_is_the_one_the_harness_runs(sample_dir: Path) -> None:
    splits = ("val_seen", "val_unseen")
    some = [e.episode_id for e in load_split(sample_dir, "val_unseen").episodes()][::-10]
    assert len(some) == 3  # listed in reverse: the run keeps the split's order
    # (A limit below the number of listed episodes of a split: the harness refuses the config.)
    for overrides in ({}, {"limit": 3}, {"episodes": some}, {"episodes": some, "limit": 3}):
        run_config = config(sample_dir, splits=splits, **overrides)
        assert selected_episodes(run_config, sample_dir) == list(
            episode_logs(run_config, sample_dir)
        ), overrides


def test_an_interrupted_run_then_resumed(sample_dir: Path, tmp_path: Path) -> None:
    run_config = config(
        sample_dir, limit=3, workers=1, executor="serial", write_logs=False, system="rule"
    )
    run_path = tmp_path / "run"
    run(run_config, run_path)
    results = run_path / "results.jsonl"
    rows = results.read_bytes().splitlines(keepends=True)
    results.write_bytes(b"".join(rows[:2]))  # killed after its first episode
    (run_path / "run.json").unlink()  # an interrupted run writes no report
    refused = score(run_path, "--out", tmp_path / "o")
    assert isinstance(refused.exception, IncompleteRunError)
    assert "2 missing episode(s)" in str(refused.exception)
    run(run_config, run_path)  # as `skyvln-eval run` again: it resumes
    assert len(read_results(results)) == 3
    scored = score(run_path, "--out", tmp_path / "o")
    assert scored.exit_code == 0, scored.output


def test_a_row_with_another_ground_truth_than_its_episode_is_never_scored(
    dataset: Path, tmp_path: Path
) -> None:
    """The goal a row is scored against is kept in the row: edited to the drone's last
    view, SR rose, and neither score (even with --data-dir) nor validate saw it."""
    run_path = run_dir(tmp_path / "run", config(dataset, limit=2), IDS[:2])
    results = read_results(run_path / "results.jsonl")
    views = results[1].gt_path_corners.copy()
    views[-1] += 0.001  # the goal moved by about 100 m
    edited = result(results[1].visited_views, views, episode_id=IDS[1])
    write_results(run_path / "results.jsonl", [results[0], edited])
    for extra in ([], ["--allow-incomplete"], ["--data-dir", str(dataset)]):
        refused = score(run_path, "--out", tmp_path / "scores", *extra)
        assert refused.exit_code != 0
        message = str(refused.exception)
        assert "1 row(s) hold another ground truth than their episode's" in message
        assert f"('val_seen/{IDS[1]}')" in message
    checked = runner.invoke(app, ["validate", str(run_path)])
    assert checked.exit_code == 1
    assert "hold another ground truth" in checked.output
    # A results file outside a run directory is checked against --data-dir's episodes.
    loose = tmp_path / "loose.jsonl"
    write_results(loose, [results[0], edited])
    refused = score(loose, "--data-dir", dataset, "--out", tmp_path / "l", "--allow-incomplete")
    assert "hold another ground truth" in str(refused.exception)
