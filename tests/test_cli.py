"""The command line: validate, summary, reproduce."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from skyvln_eval.cli import app
from tests.conftest import CliOutcome, make_record

Cli = Callable[..., CliOutcome]

runner = CliRunner()


def test_validate_reports_every_problem_and_exits_non_zero(
    dataset_factory: Callable[..., Path],
) -> None:
    bad = make_record(route_index="1_1", angle=math.nan)
    missing = make_record(route_index="2_1")
    del missing["gt_path_corners"]
    splits = {"val_seen": [make_record(), bad, missing], "train": [make_record()]}
    root = dataset_factory(splits, image_px=1000)  # the image the records describe
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 1
    output = result.output
    assert "record 1 (episode 1913__1_1), field 'angle'" in output
    assert "record 2 (episode 1913__2_1), field 'gt_path_corners': missing required key" in output
    assert "train: 1 valid record(s), ok" in output


def test_validate_notes_fields_the_format_does_not_define(
    dataset_factory: Callable[..., Path],
) -> None:
    # Kept as they are (nothing is lost), but a misspelt optional field read as absent
    # passed without a word.
    typo = make_record(route_index="1_1")
    typo["destinaton"] = typo.pop("destination")
    splits = {"val_seen": [make_record(), typo, make_record(route_index="2_1", x=1)]}
    root = dataset_factory(splits, image_px=1000)
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 0, result.output  # a note, not a problem
    assert (
        "val_seen: note: fields the AVDN format does not define (kept as they are): "
        "'destinaton' in 1 record(s); did you mean 'destination'?; 'x' in 1 record(s)"
    ) in " ".join(result.output.split())
    # convert says so too: its logs carry the fields as they are, the typo as no destination.
    out = root / "logs"
    result = runner.invoke(
        app, ["convert", "--data-dir", str(root), "--split", "val_seen", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "'destinaton' in 1 record(s); did you mean 'destination'?" in " ".join(
        result.output.split()
    )


def test_validate_notes_a_start_angle_the_official_step_would_add_to_the_first_turn(
    dataset_factory: Callable[..., Path],
) -> None:
    # An audit: the official agent adds a stored heading more than 2 degrees off the first
    # view's to the first turn; a record with one passed validate without a word.
    off = make_record(route_index="1_1", angle=40.0)  # its views face 30 degrees
    splits = {"val_seen": [make_record(), off]}
    result = runner.invoke(app, ["validate", str(dataset_factory(splits, image_px=1000))])
    assert result.exit_code == 0, result.output  # a note, not a problem
    assert (
        "val_seen: note: 1 record(s) start at an angle more than 2 degrees off their first "
        "view's heading: 1913__1_1 (40 vs 30 deg). The official agent adds such an angle"
    ) in " ".join(result.output.split())


def test_validate_passes_on_a_clean_dataset(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_unseen": [make_record()]}, image_px=1000)
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 0, result.output


def test_validate_decodes_the_map_images(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_unseen": [make_record(), make_record(route_index="1_1")]})
    image = root / "train_images" / "1913.tif"
    image.write_bytes(image.read_bytes()[:200])  # a download cut short: the file is there
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 1, result.output
    assert str(image) in result.output and "(2 record(s) use map 1913)" in result.output
    assert runner.invoke(app, ["validate", str(root), "--no-images"]).exit_code == 0


def test_validate_names_the_record_whose_ratio_does_not_describe_its_map(
    dataset_factory: Callable[..., Path],
) -> None:
    # lng_ratio ten times too large passed validate on xView-style data (no world layers);
    # on synthetic data it read as "the layers belong to another version of this map".
    wide = [make_record(lng_ratio=1e-4), make_record(route_index="1_1", lng_ratio=1e-4)]
    root = dataset_factory({"val_unseen": wide}, image_px=1000)
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 1, result.output
    file = root / "annotations" / "val_unseen_data.json"
    problem = (
        "field 'lng_ratio': the map image is 10000 px wide once width-resized (W x lng_ratio "
        "/ lat_ratio), but the record's longitude bounds span 1000.0 px of lat_ratio "
        "degrees: lng_ratio (0.0001) is not the bounds' extent per image pixel (or map_name "
        "names another map)"
    )
    output = " ".join(result.output.split())
    assert f"{file}, record 0 (episode 1913__0_1), {problem}" in output
    assert f"{file}, record 1 (episode 1913__1_1), {problem}" in output
    assert "val_unseen: 0 valid record(s), 2 problem(s) in 2 record(s)" in output


def test_validate_names_a_record_whose_map_name_names_another_map(
    dataset_factory: Callable[..., Path],
) -> None:
    # A record switched to another existing map: the map was blamed ("world layers ...
    # belong to another version of this map"), naming neither the record nor the field.
    switched = make_record(route_index="1_1", map_name="2000")
    root = dataset_factory({"val_seen": [make_record(), switched]}, image_px=1000)
    cv2.imwrite(str(root / "train_images" / "2000.tif"), np.zeros((1000, 870, 3), np.uint8))
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 1, result.output
    file = root / "annotations" / "val_seen_data.json"
    assert (
        f"{file}, record 1 (episode 2000__1_1), field 'map_name': map 2000's image is not the "
        "one this record's geo-reference describes, which is map 1913's (record 0): "
        "map_name names another map (the map image is 870 px wide once width-resized (W x "
        "lng_ratio / lat_ratio), but the record's longitude bounds span 1000.0 px of "
        "lat_ratio degrees)"
    ) in " ".join(result.output.split())
    assert "val_seen: 1 valid record(s), 1 problem(s) in 1 record(s)" in result.output


def test_validate_notes_trajectories_that_cannot_form_an_andh_full_episode(
    dataset_factory: Callable[..., Path],
) -> None:
    # A dialog without its round 1, or whose rounds disagree on last_round_idx (10**12 and
    # 2), was "ok"; convert --mode andh-full then failed naming no record. AVDN's ANDH
    # takes each record alone, so these are notes (exit 0), not problems.
    lacking = make_record(route_index="4_2", last_round_idx=2)
    first = make_record(route_index="9_1", last_round_idx=2)
    claims = make_record(route_index="9_2", last_round_idx=10**12)
    root = dataset_factory({"val_seen": [make_record(), lacking, first, claims]}, image_px=1000)
    result = runner.invoke(app, ["validate", str(root)])
    assert result.exit_code == 0, result.output
    file = root / "annotations" / "val_seen_data.json"
    output = " ".join(result.output.split())
    assert "val_seen: 4 valid record(s), ok" in output
    assert (
        f"note: {file}, record 1 (episode 1913__4_2), field 'last_round_idx': trajectory "
        "1913/4 is missing round(s) 1 (last_round_idx 2 in 1913__4_2; it holds 1913__4_2); "
        "it cannot form an ANDH-Full episode (ANDH episodes are unaffected)"
    ) in output
    assert (
        f"note: {file}, record 2 (episode 1913__9_1), field 'last_round_idx': trajectory "
        "1913/9 has rounds that disagree on last_round_idx (2 in 1913__9_1; 1000000000000 in "
        "1913__9_2); is missing round(s) 3-1000000000000 (last_round_idx 1000000000000 in "
        "1913__9_2; it holds 1913__9_1, 1913__9_2); it cannot form an ANDH-Full episode "
        "(ANDH episodes are unaffected)"
    ) in output
    assert output.count("note: ") == 2  # trajectory 0 is whole


def test_validate_names_a_bad_landmarks_file_and_its_field(
    dataset_factory: Callable[..., Path],
) -> None:
    """A synthetic map's landmarks.json that is not JSON, lacks a landmark's field or has
    another format version: each is a problem naming the file (it crashed validate)."""
    from skyvln_eval.worlds.layers import LAYERS_FORMAT, LAYERS_FORMAT_VERSION

    root = dataset_factory({"val_unseen": [make_record()]}, image_px=1000)
    landmarks = root / "world_layers" / "1913" / "landmarks.json"
    landmarks.parent.mkdir(parents=True)
    header = {"format": LAYERS_FORMAT, "version": LAYERS_FORMAT_VERSION, "map_name": "1913"}
    item = {
        "landmark_id": 1,
        "name": "a",
        "category": "building",
        "description": "d",
        "centre": [1, 2],
        "footprint": [[0, 0], [1, 0], [1, 1]],
    }
    cases = {
        "{cut": "not a JSON file",
        json.dumps({**header, "landmarks": [item]}): "landmark 0, field 'height_m': missing",
        json.dumps({**header, "landmarks": [{**item, "height_m": 3, "centre": [1]}]}): (
            "landmark 0, field 'centre': invalid"
        ),
        json.dumps({**header, "version": 0, "landmarks": []}): "format version 0",
    }
    for text, problem in cases.items():
        landmarks.write_text(text)
        result = runner.invoke(app, ["validate", str(root)])
        assert result.exit_code == 1, result.output
        output = " ".join(result.output.split())
        assert f"{landmarks}: " in output and problem in output, output
        assert "(1 record(s) use map 1913)" in output


def test_validate_a_folder_without_annotations(tmp_path: Path) -> None:
    # What validate cannot read is a wrong argument: exit 2, as other commands answer one
    # (it was 1, a problem found in what it checked).
    result = runner.invoke(app, ["validate", str(tmp_path)])
    assert result.exit_code == 2
    assert "no annotations" in result.output
    missing = runner.invoke(app, ["validate", str(tmp_path / "nope")])
    assert missing.exit_code == 2 and "nope: no such file or directory" in missing.output
    rows = tmp_path / "run" / "results.jsonl"
    rows.parent.mkdir()
    rows.write_text("{}\n")
    given = runner.invoke(app, ["validate", str(rows)])
    assert given.exit_code == 2 and f"validate its run directory, {rows.parent}" in given.output


def test_summary_skip_invalid_reports_what_it_skipped(dataset_factory: Callable[..., Path]) -> None:
    root = dataset_factory({"val_seen": [make_record(), make_record(route_index="1_1", angle="x")]})
    result = runner.invoke(app, ["summary", str(root)])
    assert result.exit_code != 0
    result = runner.invoke(app, ["summary", str(root), "--skip-invalid"])
    assert result.exit_code == 0, result.output
    assert "skipped: " in result.output and "field 'angle'" in result.output
    assert "skipped 1 invalid record(s), loaded 1" in result.output
    # Every record skipped: no means to show, and none made up ("nan", "nan-nan" were).
    none = dataset_factory({"val_seen": [make_record(angle="x")]})
    result = runner.invoke(app, ["summary", str(none), "--skip-invalid"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "skipped 1 invalid record(s), loaded 0" in result.output and "nan" not in result.output


def test_summary_of_a_folder_without_a_dataset_is_an_error(tmp_path: Path, cli: Cli) -> None:
    missing = tmp_path / "nonexistent"
    outcome = cli("summary", str(missing))
    assert outcome.code == 2 and not outcome.out
    assert f"error: {missing} does not exist; expected a dataset folder with " in outcome.err
    assert "annotations/val_seen_data.json" in outcome.err
    outcome = cli("summary", str(tmp_path))
    assert outcome.code == 2 and not outcome.out
    assert f"error: {tmp_path}: no annotation file of any split; expected " in outcome.err


def test_sample_names_the_synthetic_dataset_in_summary_and_convert(
    sample_dir: Path, tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    import skyvln_eval.converters.commands as commands

    monkeypatch.setenv("SKYVLN_EVAL_CACHE", str(sample_dir.parent))
    outcome = cli("summary", "sample")
    assert outcome.code == 0, outcome
    assert "val_unseen" in outcome.out and "no annotation file" not in outcome.err
    outcome = cli("validate", "sample", "--no-images")  # it was "no annotations/ found"
    assert outcome.code == 0, outcome
    assert f"{sample_dir} val_unseen: " in " ".join(outcome.out.split())
    converted: list[Path] = []
    monkeypatch.setattr(
        commands, "run_convert", lambda data_dir, *_, **__: converted.append(data_dir) or 0
    )
    outcome = cli("convert", "--data-dir", "sample", "--split", "val_seen", "--out", str(tmp_path))
    assert outcome.code == 0, outcome
    assert converted == [sample_dir]
    # score too: predictions of the sample, scored against its ground truth.
    from skyvln_eval.avdn import load_split
    from skyvln_eval.metrics import Prediction, write_predictions_json

    episodes = load_split(sample_dir, "val_seen").episodes()
    predictions = {e.episode_id: Prediction(e.episode_id, e.gt_path_corners) for e in episodes}
    write_predictions_json(tmp_path / "preds.json", predictions)
    args = ("--split", "val_seen", "--out", str(tmp_path / "s"))
    outcome = cli("score", str(tmp_path / "preds.json"), "--data-dir", "sample", *args)
    assert outcome.code == 0, outcome  # the ground truth replayed: every episode succeeds
    scores = (tmp_path / "s" / "scores.csv").read_text().splitlines()
    assert len(scores) == 3 + len(episodes)  # format, conventions and header lines
    # Intervals over whole trajectories (the rounds of a dialog together), and a bad unit.
    by_route = ("--split", "val_seen", "--out", str(tmp_path / "t"), "--ci-unit", "trajectory")
    outcome = cli("score", str(tmp_path / "preds.json"), "--data-dir", "sample", *by_route)
    assert outcome.code == 0, outcome
    assert ",spl,%," in (summary := (tmp_path / "t" / "summary.csv").read_text())
    assert "trajectory_bootstrap" in summary and ",bootstrap\n" not in summary
    table = cli("table", str(tmp_path / "t" / "scores.csv"), "--ci", "--ci-unit", "trajectory")
    assert table.code == 0 and "bootstrap of the trajectories" in table.out, table
    outcome = cli("score", str(tmp_path / "preds.json"), "--data-dir", "sample", *args[:2],
                  "--ci-unit", "map")  # fmt: skip
    assert outcome.code == 2 and "--ci-unit must be one of episode, trajectory" in outcome.err
    # A folder of that name is still reachable by a path that is not the bare word.
    monkeypatch.chdir(tmp_path)
    outcome = cli("summary", "./sample")
    assert outcome.code == 2 and "sample does not exist" in outcome.err


def test_help_texts_read_as_written() -> None:
    """Rich markup does not eat bracketed words, and docstring paragraphs are unwrapped
    (Typer would keep their line breaks, which break sentences on a narrower terminal)."""
    import typer.main

    wide = {"COLUMNS": "400"}
    view = runner.invoke(app, ["view", "--help"], env=wide)
    assert "Needs `pip install 'skyvln-eval[viewer]'`." in view.output
    text = runner.invoke(app, ["reproduce", "--help"], env=wide).output
    assert "has more than --fail-on-error of its episodes in error (the tables" in text

    def commands(command: Any, path: list[str]) -> Iterator[tuple[list[str], Any]]:
        yield path, command
        for name, sub in getattr(command, "commands", {}).items():
            yield from commands(sub, [*path, name])

    for path, command in commands(typer.main.get_command(app), []):
        shown = " ".join(runner.invoke(app, [*path, "--help"], env=wide).output.split())
        for param in command.params:
            for word in (getattr(param, "help", None) or "").split():
                if "[" in word:  # e.g. G[N-2]: escaped for Rich, shown as written
                    assert word.replace("\\[", "[") in shown, (path, word)


def test_running_out_of_memory_is_a_message_and_exit_2_not_a_traceback(
    cli: Callable[..., CliOutcome], monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit under `ulimit -v`: a MemoryError traceback and exit 1, the code of a run
    # with episodes in error.
    import skyvln_eval.cli as command

    def out_of_memory() -> None:
        raise MemoryError

    monkeypatch.setattr(command, "app", out_of_memory)
    outcome = cli("summary", "sample")
    assert outcome.code == 2 and "Traceback" not in outcome.err
    assert outcome.err.startswith("error: out of memory (a memory limit")
