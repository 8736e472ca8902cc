"""`skyvln-eval validate RUN_DIR`: a run directory's rows and the files of its episodes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.run_check import check_run_directory
from skyvln_eval.harness.runner import control_log_name, log_path
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics.results_io import read_results

runner = CliRunner()


def test_validate_reads_every_row_and_each_episode_s_files(
    tmp_path: Path, small_config: Callable[..., RunConfig]
) -> None:
    """It said ok on a run directory whose results.jsonl had a damaged row, or whose
    control log was cut short: only the MCAP logs were checked."""
    run_dir = tmp_path / "run"
    config = small_config(mode="dynamics", splits=("val_seen",), limit=2)
    assert run(config, run_dir).complete
    result = runner.invoke(app, ["validate", str(run_dir)])
    assert result.exit_code == 0, result.output
    assert f"{run_dir}: run directory, 2 result row(s), ok" in result.output

    first, second = read_results(run_dir / RESULTS_FILE)
    results = run_dir / RESULTS_FILE
    results.write_bytes(results.read_bytes() + b'{"episode_id": "cut\n')
    control = run_dir / control_log_name(first.split, first.episode_id)
    control.write_bytes(control.read_bytes()[:-8])
    log = log_path(run_dir, second.split, second.episode_id)
    log.unlink()
    check = check_run_directory(run_dir)
    assert check.rows == 2 and len(check.problems) == 3, check.problems
    damaged, cut, gone = check.problems
    assert damaged.startswith(f"{results} line 4: damaged row (not JSON")
    assert cut == (
        f"{control}: damaged: truncated or not a parquet file (the control log of episode "
        f"{first.split}/{first.episode_id})"
    )
    assert gone == f"{log}: missing (the run log of episode {second.split}/{second.episode_id})"
    # A folder of runs (a reproduction's runs/) checks each of them.
    for target in (run_dir, tmp_path):
        result = runner.invoke(app, ["validate", str(target)])
        assert result.exit_code == 1
        assert f"{run_dir}: run directory, 2 result row(s), 3 problem(s)" in result.output


def test_an_unfinished_run_is_a_note_not_a_problem(
    tmp_path: Path, small_config: Callable[..., RunConfig]
) -> None:
    run_dir = tmp_path / "run"
    assert run(small_config(limit=1), run_dir).complete
    (run_dir / "config.yaml").write_text(
        (run_dir / "config.yaml").read_text().replace("limit: 1", "limit: 2")
    )
    result = runner.invoke(app, ["validate", str(run_dir)])
    assert result.exit_code == 0, result.output
    assert "note: 1 of its 2 episode(s) have no result row yet" in result.output
    # A writer killed before its rename left a temporary file: said (it said ok).
    [row] = read_results(run_dir / RESULTS_FILE)
    log = log_path(run_dir, row.split, row.episode_id)
    (log.parent / f".{log.name}.k3j9x2a1.tmp").write_bytes(b"half a log")
    result = runner.invoke(app, ["validate", str(run_dir)])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "1 temporary file(s) of writers stopped before they finished" in said
    assert "(the next run or resume removes them)" in said


def test_a_repeated_row_is_a_problem_that_score_would_refuse(
    tmp_path: Path, small_config: Callable[..., RunConfig]
) -> None:
    # An audit's results.jsonl with a row given twice: validate said ok, score refused it.
    run_dir = tmp_path / "run"
    assert run(small_config(limit=1), run_dir).complete
    results = run_dir / RESULTS_FILE
    (row,) = read_results(results)
    lines = results.read_bytes().splitlines(keepends=True)
    results.write_bytes(b"".join([*lines, lines[1]]))
    check = check_run_directory(run_dir)
    assert check.problems == [
        f"{results}: 1 episode row(s) repeated (e.g. {row.split}/{row.episode_id}); `score` "
        "refuses the file, and resuming the run (the same command) keeps each episode's "
        "latest row"
    ]


def test_a_damaged_run_json_is_a_problem(
    tmp_path: Path, small_config: Callable[..., RunConfig]
) -> None:
    # It records the folder a relative data path named at launch: damaged, that check
    # went without a word (an audit), and validate said ok.
    run_dir = tmp_path / "run"
    assert run(small_config(splits=("val_seen",), limit=1), run_dir).complete
    assert not check_run_directory(run_dir).problems
    (run_dir / "run.json").write_text('{"system": "aud')
    (problem,) = check_run_directory(run_dir).problems
    assert problem.startswith(f"{run_dir / 'run.json'}: cannot be read (")
