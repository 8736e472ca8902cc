"""The command line: validate, summary, reproduce."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from typer.testing import CliRunner

from skyvln_eval.cli import app
from tests.conftest import make_record

runner = CliRunner()


def test_validate_reports_every_problem_and_exits_non_zero(
    dataset_factory: Callable[..., Path],
) -> None:
    bad = make_record(route_index="1_1", angle=math.nan)
    missing = make_record(route_index="2_1")
    del missing["gt_path_corners"]
    root = dataset_factory({"val_seen": [make_record(), bad, missing], "train": [make_record()]})
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 1
    output = result.output
    assert "record 1 (episode 1913__1_1), field 'angle'" in output
    assert "record 2 (episode 1913__2_1), field 'gt_path_corners': missing required key" in output
    assert "train: 1 valid record(s), ok" in output


def test_validate_passes_on_a_clean_dataset(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_unseen": [make_record()]})
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 0, result.output


def test_validate_a_folder_without_annotations(tmp_path: Path) -> None:
    result = runner.invoke(app, ["validate", str(tmp_path)])
    assert result.exit_code == 1
    assert "no annotations" in result.output


def test_summary_skip_invalid_reports_what_it_skipped(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_seen": [make_record(), make_record(route_index="1_1", angle="x")]})
    result = runner.invoke(app, ["summary", str(root)])
    assert result.exit_code != 0
    result = runner.invoke(app, ["summary", str(root), "--skip-invalid"])
    assert result.exit_code == 0, result.output
    assert "skipped: " in result.output and "field 'angle'" in result.output
    assert "skipped 1 invalid record(s), loaded 1" in result.output
