"""Broken files and full disks, through `skyvln-eval run` as a user meets them: a corrupt map
image, a results.jsonl damaged in the middle or at its end, a disk that fills up while
results or run MCAPs are written. Each gives a clear message and a non-zero exit, and
nothing already done is lost or duplicated: the same command then resumes."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from skyvln_eval.errors import IncompleteRunError
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.store import DAMAGED_FILE, RESULTS_FILE
from skyvln_eval.metrics import EpisodeResult, read_results
from tests.conftest import REPO, CliOutcome, make_record, write_dataset
from tests.harness.compare import same_runs

Cli = Callable[..., CliOutcome]
MakeConfig = Callable[..., RunConfig]


def _write(config: RunConfig, path: Path) -> Path:
    path.write_text(yaml.safe_dump(config.model_dump(mode="json")))
    return path


def _limited_run(
    config_file: Path, out: Path, max_file_bytes: int
) -> subprocess.CompletedProcess[str]:
    """`skyvln-eval run` in a process that may not write any file past ``max_file_bytes``
    (RLIMIT_FSIZE): every write beyond fails with EFBIG, as a full disk fails with ENOSPC."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (max_file_bytes, max_file_bytes))

    command = [sys.executable, "-m", "skyvln_eval.cli", "run", str(config_file), "--out", str(out)]
    return subprocess.run(
        command,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"},
        preexec_fn=limit,  # only a resource limit: safe before exec
        capture_output=True,
        text=True,
        timeout=300,
    )


def _reference(config: RunConfig, tmp_path: Path) -> tuple[list[EpisodeResult], list[int]]:
    """The rows of an uninterrupted run of ``config`` and the byte length of each line of
    its results file (the header first)."""
    run(config, tmp_path / "reference")
    path = tmp_path / "reference" / RESULTS_FILE
    return read_results(path), [len(line) + 1 for line in path.read_bytes().split(b"\n")[:-1]]


def test_a_corrupt_map_image_fails_the_run_naming_the_file(tmp_path: Path, cli: Cli) -> None:
    records = [make_record(route_index=f"{i}_1") for i in range(2)]
    data = write_dataset(tmp_path / "data", {"val_unseen": records})
    image = data / "train_images" / "1913.tif"
    image.write_bytes(b"II*\x00" + b"\x13" * 500)  # a TIFF header, then garbage
    config = {
        "system": "corrupt map",
        "data": str(data),
        "splits": ["val_unseen"],
        "executor": "serial",
        "agent": {"name": "random"},
    }
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config))
    outcome = cli("run", str(path), "--out", str(tmp_path / "run"))
    assert outcome.code == 1, outcome
    assert "corrupt map: 2 of 2 episode(s) ended in error" in outcome.err
    assert f"MapImageError: {image}: not a readable image" in outcome.err
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    assert [r.status for r in rows] == ["error", "error"]


def test_resuming_over_damaged_rows_sets_them_aside_and_runs_their_episodes_again(
    tmp_path: Path, small_config: MakeConfig, cli: Cli
) -> None:
    config = small_config(limit=4, write_logs=False)
    run_dir = tmp_path / "run"
    run(config, run_dir)
    reference = read_results(run_dir / RESULTS_FILE)
    path = run_dir / RESULTS_FILE
    lines = path.read_bytes().split(b"\n")
    middle, last = lines[2], lines[4]
    lines[2] = middle[: len(middle) // 3] + b"\xff\xfe"  # a bad block in the middle
    lines[4] = last[: len(last) // 2]  # the last row cut short, yet its line ends
    path.write_bytes(b"\n".join(lines))
    assert path.read_bytes().endswith(b"\n")

    outcome = cli("run", str(_write(config, tmp_path / "run.yaml")), "--out", str(run_dir))
    assert outcome.code == 0, outcome
    episodes = {line: reference[n].episode_id for line, n in ((3, 1), (5, 3))}
    for line, episode in episodes.items():
        assert f"results.jsonl line {line}: damaged row (" in outcome.out
        assert (
            f"set aside in {run_dir / DAMAGED_FILE}; episode val_unseen/{episode} runs again"
            in (outcome.out)
        )
    assert "2 already done, 2 run now" in outcome.out
    aside = (run_dir / DAMAGED_FILE).read_text()
    assert aside.count('"line":3') == 1 and aside.count('"line":5') == 1
    same_runs(read_results(path), reference)


def test_a_full_disk_while_results_are_appended_keeps_every_completed_row(
    tmp_path: Path, small_config: MakeConfig, cli: Cli
) -> None:
    config = small_config(limit=4, write_logs=False)
    reference, sizes = _reference(config, tmp_path)
    # Room for the header, two rows and half of the third.
    room = sum(sizes[:3]) + sizes[3] // 2
    config_file = _write(config, tmp_path / "run.yaml")
    run_dir = tmp_path / "run"
    full = _limited_run(config_file, run_dir, room)
    assert full.returncode == 2, full.stdout + full.stderr
    assert "Traceback" not in full.stderr
    message = full.stderr
    assert f"error: cannot record episode val_unseen/{reference[2].episode_id} in " in message
    assert "File too large (EFBIG)" in message and "full" in message
    assert "The 2 row(s) recorded before it are intact" in message
    assert "run the same command again" in message
    kept = (run_dir / RESULTS_FILE).read_bytes()
    assert kept.endswith(b"\n") and kept.count(b"\n") == 3  # header and two whole rows
    assert not (run_dir / "run.lock").read_bytes(), "the lock is let go"
    # run.json says where the launch got (an audit: it said what the launch began with,
    # every episode missing).
    report = json.loads((run_dir / "run.json").read_text())
    assert report["finished"] is False and len(report["missing"]) == 2

    resumed = cli("run", str(config_file), "--out", str(run_dir))
    assert resumed.code == 0, resumed
    assert "2 already done, 2 run now" in resumed.out
    assert "damaged" not in resumed.out  # nothing partial was left behind
    same_runs(read_results(run_dir / RESULTS_FILE), reference)


def test_a_full_disk_while_run_logs_are_written_stops_the_run_at_once(
    tmp_path: Path, small_config: MakeConfig, cli: Cli
) -> None:
    config = small_config(limit=4, observations_in_logs=True)
    reference, sizes = _reference(config, tmp_path)
    biggest_row = max(sizes)
    smallest_log = min(p.stat().st_size for p in (tmp_path / "reference").rglob("*.mcap"))
    room = 3 * biggest_row  # results fit, no run MCAP does
    assert room < smallest_log
    config_file = _write(config, tmp_path / "run.yaml")
    run_dir = tmp_path / "run"
    full = _limited_run(config_file, run_dir, room)
    assert full.returncode == 1, full.stdout + full.stderr
    assert "Traceback" not in full.stderr
    assert "the run stopped early: cannot write the run's files: " in full.stderr
    assert f"{run_dir / 'logs' / 'val_unseen'}/" in full.stderr  # names the file
    assert ".mcap: File too large (EFBIG)" in full.stderr and "free some space" in full.stderr
    with pytest.raises(IncompleteRunError, match="only record that the run stopped"):
        read_results(run_dir / RESULTS_FILE)  # the one row is the stop, not a result
    rows = read_results(run_dir / RESULTS_FILE, allow_incomplete=True)
    stops = [line for line in (run_dir / RESULTS_FILE).read_text().splitlines() if line]
    assert not rows and len(stops) == 2, "a header, then the stop at the first episode"
    assert not list(run_dir.rglob("*.mcap")) and not list(run_dir.rglob(".*.tmp"))

    resumed = cli("run", str(config_file), "--out", str(run_dir))
    assert resumed.code == 0, resumed
    assert "0 already done, 4 run now" in resumed.out  # the stopped episode runs again
    same_runs(read_results(run_dir / RESULTS_FILE), reference)
    assert len(list(run_dir.rglob("*.mcap"))) == 4
