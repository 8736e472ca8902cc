"""The AVDN-format sample with RGB-only maps (its semantic layers withheld, as on xView):
`run` with the default simulated detector refuses to start (exit 2, naming the detector,
the data and the alternatives); with GroundingDINO on RGB the episodes run and are scored."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import read_log
from skyvln_eval.harness import RunConfig
from skyvln_eval.harness.preflight import PreflightError, preflight
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import MetricConventions, read_results, score_results
from skyvln_eval.worlds.layers import LAYERS_DIR
from tests.conftest import REPO
from tests.vision_models import build_tiny_grounding_dino, count_model_loads


@pytest.fixture(scope="module")
def rgb_only_data(sample_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the sample without its world layers: annotations and RGB maps only."""
    copy = tmp_path_factory.mktemp("rgb-only") / "avdn"
    shutil.copytree(sample_dir, copy, ignore=shutil.ignore_patterns(LAYERS_DIR))
    assert not (copy / LAYERS_DIR).exists() and (copy / "train_images").is_dir()
    return copy


def write_config(path: Path, data: Path, **settings: Any) -> Path:
    config = {
        "system": "rgb-only check",
        "data": str(data),
        "splits": ["val_seen"],
        "limit": 2,
        "workers": 1,
        "executor": "serial",
        "write_logs": False,
    }
    path.write_text(yaml.safe_dump(config | settings), encoding="utf-8")
    return path


def test_the_simulated_detector_refuses_rgb_only_data_with_exit_code_2(
    rgb_only_data: Path, tmp_path: Path
) -> None:
    config = write_config(tmp_path / "simulated.yaml", rgb_only_data)
    out = tmp_path / "run"
    refused = subprocess.run(
        [sys.executable, "-m", "skyvln_eval.cli", "run", str(config), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
        check=False,
    )
    assert refused.returncode == 2, refused.stderr
    message = " ".join(refused.stderr.split())  # the message wraps on narrow terminals
    assert "detector 'simulated'" in message  # the detector
    assert str(rgb_only_data) in message and "RGB only" in message  # the data
    assert "'grounding_dino'" in message and "'vlm'" in message  # the alternatives
    assert "sensors {semantic: false}" in message
    assert not (out / RESULTS_FILE).exists()  # refused before any episode ran


def test_a_detector_whose_sensor_is_off_is_refused_naming_the_sensor(rgb_only_data: Path) -> None:
    settings = {"system": "no camera", "data": str(rgb_only_data), "sensors": {"semantic": False}}
    config = RunConfig.model_validate(settings)
    with pytest.raises(PreflightError, match=r"'simulated' needs the semantic sensor\(s\)"):
        preflight(config, rgb_only_data, ["9101"])


def test_grounding_dino_without_weights_or_with_a_bad_device_is_refused_before_flying(
    rgb_only_data: Path, tmp_path: Path
) -> None:
    # An audit: every episode ended in error (each trying to load the weights again)
    # where the run could have been refused at once.
    absent = {"name": "grounding_dino", "model": str(tmp_path / "no-such-model")}
    settings = {"system": "gd", "data": str(rgb_only_data), "sensors": {"semantic": False}}
    config = RunConfig.model_validate(settings | {"agent": {"detector": absent}})
    with pytest.raises(PreflightError, match=r"detector model folder .*no-such-model does not"):
        preflight(config, rgb_only_data, ["9101"])
    model = build_tiny_grounding_dino(tmp_path / "grounding-dino-tiny")
    bad = {"name": "grounding_dino", "model": str(model), "device": "gpu0"}
    config = RunConfig.model_validate(settings | {"agent": {"detector": bad}})
    with pytest.raises(PreflightError, match=r"detector device 'gpu0' is not a torch device"):
        preflight(config, rgb_only_data, ["9101"])


def test_grounding_dino_runs_on_rgb_only_data_and_episodes_are_scored(
    rgb_only_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = build_tiny_grounding_dino(tmp_path / "grounding-dino-tiny")
    loads = count_model_loads(monkeypatch)
    detector = {"name": "grounding_dino", "model": str(model), "box_threshold": 0.3}
    config = write_config(
        tmp_path / "grounding-dino.yaml",
        rgb_only_data,
        agent={"name": "skyvln", "detector": detector, "llm": {"backend": "rule"}},
        sensors={"semantic": False},
        write_logs=True,
    )
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(config), "--out", str(out)])
    assert result.exit_code == 0, result.output
    results = read_results(out / RESULTS_FILE)
    assert len(results) == 2 and all(r.status != "error" for r in results)
    scores = score_results(results, MetricConventions())
    assert len(scores) == 2
    assert set(scores["detector"]) == {f"grounding_dino:{model}"}  # named with its weights
    assert set(scores["success"]) <= {0.0, 1.0} and all(math.isfinite(v) for v in scores["ne_m"])
    assert loads == [str(model.resolve())]  # the serial worker loaded the weights once
    resolved = yaml.safe_load((out / "config.yaml").read_text(encoding="utf-8"))
    assert resolved["agent"]["detector"]["name"] == "grounding_dino"
    assert resolved["sensors"]["semantic"] is False
    # GroundingDINO's boxes reached the agent as landmarks labelled with its phrases.
    steps = [
        message.decode()
        for log in sorted((out / "logs").rglob("*.mcap"))
        for message in read_log(log).topic(t.TOPIC_AGENT_STEP)
    ]
    sightings = [s for step in steps for s in step["trace"]["sightings"]]
    phrases = {g.get("landmark") for step in steps for g in step["trace"]["subgoals"]}
    assert sightings and {s["label"] for s in sightings} <= phrases - {None}
