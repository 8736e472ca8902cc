"""The command line: validate, summary, reproduce."""

from __future__ import annotations

import json
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


def test_reproduce_on_the_sample_writes_a_summary(sample_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = runner.invoke(app, ["reproduce", "--data-dir", str(sample_dir), "--out", str(out)])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "dataset_summary.json").read_text())
    assert [s["split"] for s in summary["splits"]] == [
        "train",
        "val_seen",
        "val_unseen",
        "test_unseen",
    ]
    assert all(s["gt_replay_min_iou"] > 1 - 1e-9 for s in summary["splits"])
