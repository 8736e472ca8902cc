"""Split conversion: manifest, re-runs that skip, workers that change nothing, failures."""

from __future__ import annotations

import errno
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from skyvln_eval import fileio
from skyvln_eval.avdn import distance_m, load_split, view_centre
from skyvln_eval.converters import ConvertOptions, batch, read_log
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.batch import convert_split, episode_file_name
from skyvln_eval.converters.left_out import LEFT_OUT_NAME, LeftOut, read_left_out
from skyvln_eval.converters.manifest import (
    MANIFEST_NAME,
    manifest_left_out_sha256,
    read_manifest,
    write_manifest,
)
from skyvln_eval.converters.validate import check_manifest_folder
from skyvln_eval.errors import AvdnValidationError, ConfigError, FormatVersionError
from skyvln_eval.fileio import sha256_file
from tests.conftest import make_record
from tests.converters.conftest import ConvertedSample


def _tree(folder: Path) -> dict[str, str]:
    return {p.name: sha256_file(p) for p in sorted(folder.iterdir())}


def test_manifest_lists_every_episode_with_its_figures(converted_sample: ConvertedSample) -> None:
    for (split, mode), report in converted_sample.reports.items():
        rows = read_manifest(report.manifest_path)
        episodes = converted_sample.episodes[(split, mode)]
        assert [r.episode_id for r in rows] == [e.episode_id for e in episodes]
        for row, episode in zip(rows, episodes, strict=True):
            centres = view_centre(episode.gt_path_corners)
            assert (row.split, row.mode, row.map_name) == (split, mode, episode.map_name)
            assert row.rounds == episode.records[-1].round_index
            assert row.gt_views == len(centres)
            assert row.d_net_m == pytest.approx(float(distance_m(centres[0], centres[-1])))
            assert row.gt_length_m == pytest.approx(
                float(np.sum(distance_m(centres[1:], centres[:-1])))
            )
            assert row.gt_length_m >= row.d_net_m - 1e-9
            path = report.out_dir / row.file_name
            assert row.file_name == episode_file_name(episode.episode_id)
            assert row.sha256 == sha256_file(path) and row.size_bytes == path.stat().st_size
        names = {p.name for p in report.out_dir.iterdir()}
        assert names == {r.file_name for r in rows} | {MANIFEST_NAME, LEFT_OUT_NAME}
        assert read_left_out(report.left_out_path) == []


def test_rerun_skips_converted_episodes_and_workers_give_identical_output(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    data_dir = converted_sample.data_dir
    reference = converted_sample.reports[("val_seen", "andh")]
    parallel = convert_split(data_dir, "val_seen", tmp_path, "andh", workers=2)
    assert parallel.count("converted") == len(parallel.outcomes) > 0
    assert _tree(parallel.out_dir) == _tree(reference.out_dir), "byte-identical for 1 and 2 workers"
    again = convert_split(data_dir, "val_seen", tmp_path, "andh", workers=2)
    assert again.count("skipped") == len(again.outcomes) and again.count("converted") == 0
    assert _tree(again.out_dir) == _tree(reference.out_dir)


def test_a_rerun_trusts_the_manifests_hashes_and_reads_back_only_other_files(
    converted_sample: ConvertedSample, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data_dir = converted_sample.data_dir
    first = convert_split(data_dir, "val_seen", tmp_path, "andh")
    folder, expected = first.out_dir, _tree(first.out_dir)
    read: list[str] = []
    real = batch.read_log

    def counted(path: Path) -> object:
        read.append(Path(path).name)
        return real(path)

    monkeypatch.setattr(batch, "read_log", counted)
    again = convert_split(data_dir, "val_seen", tmp_path, "andh")
    assert again.count("skipped") == len(first.rows) and read == [], "bytes as recorded"
    assert again.rows == first.rows
    # The same size, other bytes: not trusted, read back (and converted again if damaged).
    victim = folder / first.rows[1].file_name
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    convert_split(data_dir, "val_seen", tmp_path, "andh")
    assert read == [victim.name]
    assert _tree(folder) == expected
    # No manifest (a conversion cut short before it): every file is read back, all skip.
    read.clear()
    (folder / MANIFEST_NAME).unlink()
    report = convert_split(data_dir, "val_seen", tmp_path, "andh")
    assert report.count("skipped") == len(first.rows) and len(read) == len(first.rows)
    assert _tree(folder) == expected


def test_damaged_stale_and_leftover_files_are_handled(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    data_dir = converted_sample.data_dir
    first = convert_split(data_dir, "test_unseen", tmp_path, "andh-full")
    folder = first.out_dir
    expected = _tree(folder)
    victim = folder / first.rows[0].file_name
    victim.write_bytes(victim.read_bytes()[:-10])  # damaged: must be converted again
    (folder / "9999__1_1.mcap").write_bytes(b"stale")  # not an episode of this split
    (folder / ".x.mcap.123.tmp").write_bytes(b"left by a killed run")
    report = convert_split(data_dir, "test_unseen", tmp_path, "andh-full")
    assert report.count("converted") == 1 and report.count("skipped") == len(first.rows) - 1
    assert report.removed_stale == [
        batch.RemovedLog("9999__1_1.mcap", "not an episode of this split and mode")
    ]
    assert _tree(folder) == expected


def test_an_interrupted_conversion_leaves_only_whole_files(
    converted_sample: ConvertedSample, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = {"n": 0}
    real = batch.convert_episode

    def flaky(*args: object, **kwargs: object) -> None:
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # like Ctrl-C in the middle of the third episode
        real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(batch, "convert_episode", flaky)
    with pytest.raises(KeyboardInterrupt):
        convert_split(converted_sample.data_dir, "val_unseen", tmp_path, "andh")
    folder = tmp_path / "val_unseen" / "andh"
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        episode_file_name(e.episode_id)
        for e in converted_sample.episodes[("val_unseen", "andh")][:2]
    )
    monkeypatch.setattr(batch, "convert_episode", real)
    report = convert_split(converted_sample.data_dir, "val_unseen", tmp_path, "andh")
    assert report.count("skipped") == 2 and report.count("converted") == len(report.outcomes) - 2
    assert _tree(folder) == _tree(converted_sample.reports[("val_unseen", "andh")].out_dir)


def test_failures_and_invalid_records_are_reported_not_lost(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    good = make_record(route_index="1_1")
    bad = make_record(route_index="2_1", angle="north")
    other_map = make_record(map_name="77", route_index="3_1")
    root = dataset_factory({"val_seen": [good, bad, other_map]}, maps=("1913", "77"))
    with pytest.raises(AvdnValidationError, match="angle"):
        convert_split(root, "val_seen", tmp_path)
    (root / "train_images" / "77.tif").write_bytes(b"not a tiff")
    report = convert_split(root, "val_seen", tmp_path, skip_invalid=True)
    assert [i.record_index for i in report.invalid] == [1]
    assert [(o.episode_id, o.status) for o in report.outcomes] == [
        ("1913__1_1", "converted"),
        ("77__3_1", "failed"),
    ]
    assert "77.tif" in (report.failed[0].note or "")
    assert [r.episode_id for r in read_manifest(report.manifest_path)] == ["1913__1_1"]
    # The folder says what it lacks and why, not only the conversion's stderr.
    assert read_left_out(report.left_out_path) == [
        LeftOut(
            "invalid_record",
            "1913__2_1",
            1,
            ("field 'angle': expected a number, got string 'north'",),
        ),
        LeftOut("failed_episode", "77__3_1", None, (report.failed[0].note or "",)),
    ]


def test_records_that_would_crash_the_writer_are_skipped_as_invalid(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    # A lone surrogate stopped the whole batch (UnicodeEncodeError, nothing written), a
    # 401-digit angle raised OverflowError in validation.
    records = [
        make_record(route_index="1_1", instructions="[INS] \ud83d go"),
        make_record(route_index="2_1", angle=10**400),
        make_record(route_index="3_1"),
    ]
    root = dataset_factory({"val_seen": records})
    with pytest.raises(AvdnValidationError, match="not valid Unicode text"):
        convert_split(root, "val_seen", tmp_path)
    report = convert_split(root, "val_seen", tmp_path, skip_invalid=True)
    assert [(i.record_index, i.field) for i in report.invalid] == [
        (0, "instructions"),
        (1, "angle"),
    ]
    assert [r.episode_id for r in read_manifest(report.manifest_path)] == ["1913__3_1"]


def test_a_log_this_run_could_not_make_again_is_removed_with_the_true_reason(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    records = [make_record(route_index="1_1"), make_record(map_name="77", route_index="2_1")]
    root = dataset_factory({"val_seen": records}, maps=("1913", "77"))
    assert convert_split(root, "val_seen", tmp_path).count("converted") == 2
    # Its map changed to garbage, the other's record to invalid: neither log is of this
    # input any more. They were removed as 'not an episode of this split and mode'.
    (root / "train_images" / "77.tif").write_bytes(b"not a tiff")
    records[0]["angle"] = "north"
    (root / "annotations" / "val_seen_data.json").write_text(json.dumps(records))
    report = convert_split(root, "val_seen", tmp_path, skip_invalid=True)
    assert [name for name, _ in report.removed_stale] == ["1913__1_1.mcap", "77__2_1.mcap"]
    invalid, failed = (reason for _, reason in report.removed_stale)
    assert invalid == (
        "its record 0 was left out as invalid (field 'angle': expected a number, got string "
        "'north')"
    )
    assert failed.startswith("this run could not convert it (") and "77.tif" in failed
    assert sorted(p.name for p in report.out_dir.iterdir()) == [LEFT_OUT_NAME, MANIFEST_NAME]


_convert_map = batch.run_map_job  # the real one, also in worker processes


def dies_on_map_77(job: batch.MapJob) -> list[batch.EpisodeOutcome]:
    if job.map_name == "77":
        os._exit(9)  # as a crash in native code or the out-of-memory killer would
    return _convert_map(job)


def test_a_worker_process_that_dies_fails_only_its_maps_episodes(
    dataset_factory: Callable[..., Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    records = [
        make_record(route_index="1_1"),
        make_record(map_name="77", route_index="3_1"),
        make_record(route_index="2_1"),
    ]
    root = dataset_factory({"val_seen": records}, maps=("1913", "77"))
    monkeypatch.setattr(batch, "run_map_job", dies_on_map_77)
    report = convert_split(root, "val_seen", tmp_path, workers=2)
    assert [(o.episode_id, o.status) for o in report.outcomes] == [
        ("1913__1_1", "converted"),
        ("77__3_1", "failed"),
        ("1913__2_1", "converted"),
    ]
    note = report.failed[0].note or ""
    assert "map 77" in note and "worker process exited with code 9" in note
    assert [r.episode_id for r in read_manifest(report.manifest_path)] == [
        "1913__1_1",
        "1913__2_1",
    ]


def test_incomplete_trajectories_are_refused_in_full_mode(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    root = dataset_factory({"val_seen": [make_record(route_index="1_2", last_round_idx=2)]})
    with pytest.raises(AvdnValidationError, match="missing round"):
        convert_split(root, "val_seen", tmp_path, "andh-full")
    report = convert_split(root, "val_seen", tmp_path, "andh-full", skip_invalid=True)
    assert report.outcomes == [] and "missing round" in report.incomplete[0].message
    # No last_round_idx and an invalid final round: rounds 1-2 are not the trajectory.
    rounds = [make_record(route_index=f"7_{k}") for k in (1, 2, 3)]
    for record in rounds:
        del record["last_round_idx"]
    rounds[2]["angle"] = "north"
    root = dataset_factory({"val_seen": rounds})
    report = convert_split(root, "val_seen", tmp_path / "b", "andh-full", skip_invalid=True)
    assert report.outcomes == [] and read_manifest(report.manifest_path) == []
    assert [i.field for i in report.invalid] == ["angle"]
    assert [e.kind for e in read_left_out(report.left_out_path)] == [
        "invalid_record",
        "incomplete_trajectory",
    ]
    assert "round 3 (record 2) was left out" in report.incomplete[0].message


def test_manifest_version_is_checked(tmp_path: Path) -> None:
    path = tmp_path / MANIFEST_NAME
    pq.write_table(pa.table({"episode_id": ["a"]}), path)
    with pytest.raises(FormatVersionError, match="skyvln-eval convert"):
        read_manifest(path)


def test_options_are_part_of_the_skip_decision(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    data_dir = converted_sample.data_dir
    convert_split(data_dir, "val_seen", tmp_path, "andh")
    report = convert_split(
        data_dir, "val_seen", tmp_path, "andh", options=ConvertOptions(observations=False)
    )
    assert report.count("converted") == len(report.outcomes)
    episode = load_split(data_dir, "val_seen").episodes("andh")[0]
    log = read_log(report.out_dir / episode_file_name(episode.episode_id))
    assert t.TOPIC_GT_OBSERVATION not in log.summary().topic_counts


def test_manifest_check_catches_renamed_and_unlisted_files(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    folder = tmp_path / "copy"
    shutil.copytree(converted_sample.reports[("val_seen", "andh")].out_dir, folder)
    assert check_manifest_folder(folder) == []
    rows = read_manifest(folder / MANIFEST_NAME)
    recorded = manifest_left_out_sha256(folder / MANIFEST_NAME)
    write_manifest(
        folder / MANIFEST_NAME, [replace(rows[0], episode_id="42__9_1"), *rows[2:]], recorded
    )
    problems = [str(i) for i in check_manifest_folder(folder)]
    assert problems == [
        f"{folder / MANIFEST_NAME}, record 0 (episode 42__9_1), field 'file_name': "
        f"file name {rows[0].file_name} is not 42__9_1.mcap",
        f"{folder / rows[1].file_name}: not listed in {MANIFEST_NAME}",
    ]


def test_a_folder_without_its_list_of_what_was_left_out_is_not_complete(
    converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    # Deleting left_out.json made a folder that lacks episodes pass validation as complete.
    folder = tmp_path / "copy"
    shutil.copytree(converted_sample.reports[("val_seen", "andh")].out_dir, folder)
    assert check_manifest_folder(folder) == []
    left_out = folder / LEFT_OUT_NAME
    assert manifest_left_out_sha256(folder / MANIFEST_NAME) == sha256_file(left_out)
    original = left_out.read_bytes()
    left_out.write_bytes(original.replace(b'"left_out": []', b'"left_out": [ ]'))
    assert [str(i) for i in check_manifest_folder(folder)] == [
        f"{left_out}: differs from the one the conversion wrote (its sha256 is in {MANIFEST_NAME})"
    ]
    left_out.unlink()
    assert [str(i) for i in check_manifest_folder(folder)] == [
        f"{left_out}: missing: what the conversion left out, and why, is no longer told"
    ]


def test_a_map_image_that_does_not_decode_is_read_once_and_fails_each_episode(
    dataset_factory: Callable[..., Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    records = [make_record(route_index=f"{k}_1") for k in range(3)]
    root = dataset_factory({"val_seen": records})
    (root / "train_images" / "1913.tif").write_bytes(b"not a tiff")
    reads = []
    load = batch.load_map_bgr
    monkeypatch.setattr(batch, "load_map_bgr", lambda *a: reads.append(a) or load(*a))
    report = convert_split(root, "val_seen", tmp_path, workers=1)
    assert report.count("failed") == 3 and len(reads) == 1  # not decoded again per episode
    notes = {outcome.note for outcome in report.outcomes if outcome.status == "failed"}
    assert len(notes) == 1 and "1913.tif" in notes.pop()


def test_an_episode_whose_log_cannot_be_written_fails_alone(
    dataset_factory: Callable[..., Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An OSError of one file (disk full, a name too long) stopped the whole batch, with no
    # manifest and no list of what was left out.
    root = dataset_factory({"val_seen": [make_record(route_index=f"{i}_1") for i in range(3)]})
    real = batch.convert_episode

    def disk_full_on_the_second(episode: Any, *args: Any, **kwargs: Any) -> None:
        if episode.episode_id == "1913__1_1":
            raise OSError(errno.ENOSPC, "No space left on device")
        real(episode, *args, **kwargs)

    monkeypatch.setattr(batch, "convert_episode", disk_full_on_the_second)
    report = convert_split(root, "val_seen", tmp_path)
    assert [(o.episode_id, o.status) for o in report.outcomes] == [
        ("1913__0_1", "converted"),
        ("1913__1_1", "failed"),
        ("1913__2_1", "converted"),
    ]
    assert "No space left on device" in (report.failed[0].note or "")
    assert [e.episode_id for e in read_left_out(report.left_out_path)] == ["1913__1_1"]
    assert sorted(p.name for p in report.out_dir.glob("*.mcap")) == [
        "1913__0_1.mcap",
        "1913__2_1.mcap",
    ]


def test_an_output_folder_that_takes_no_files_is_one_clear_error(
    dataset_factory: Callable[..., Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = dataset_factory({"val_seen": [make_record(route_index="1_1")]})

    def read_only(*args: Any, **kwargs: Any) -> Any:
        raise PermissionError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(fileio.tempfile, "TemporaryFile", read_only)
    with pytest.raises(ConfigError, match=r"output folder .*val_seen/andh cannot take files"):
        convert_split(root, "val_seen", tmp_path)


def test_a_rerun_deletes_only_logs_a_conversion_wrote(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    root = dataset_factory({"val_seen": [make_record(route_index="1_1")]})
    folder = convert_split(root, "val_seen", tmp_path).out_dir
    (folder / "flight notes.mcap").write_bytes(b"a user's own recording")
    (folder / "1913__5_1.mcap").write_bytes(b"named as an episode log: a conversion's")
    report = convert_split(root, "val_seen", tmp_path)
    assert [r.file_name for r in report.removed_stale] == ["1913__5_1.mcap"]
    assert report.foreign_files == ["flight notes.mcap"]
    assert (folder / "flight notes.mcap").read_bytes() == b"a user's own recording"
    # validate still says the folder holds a file its manifest does not list.
    assert [i.message for i in check_manifest_folder(folder)] == [f"not listed in {MANIFEST_NAME}"]


def test_conversions_into_one_folder_take_turns(
    dataset_factory: Callable[..., Path], tmp_path: Path
) -> None:
    # An audit: two `convert` runs into one folder at once removed each other's temporary
    # files and a finished log (one reported 40 converted; the folder held 39).
    import threading

    root = dataset_factory({"val_seen": [make_record(route_index=f"{i}_1") for i in range(2)]})
    out = tmp_path / "out"
    reports: list[Any] = []
    with fileio.exclusive_lock(out / ".val_seen-andh.lock"):  # another conversion's turn
        waiting = threading.Thread(
            target=lambda: reports.append(convert_split(root, "val_seen", out))
        )
        waiting.start()
        waiting.join(timeout=3.0)
        assert waiting.is_alive() and not reports, "it converted during another's turn"
    waiting.join()
    assert reports[0].count("converted") == 2
    assert check_manifest_folder(reports[0].out_dir) == []
