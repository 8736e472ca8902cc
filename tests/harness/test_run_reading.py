"""`run_results`: a run's rows in Python, checked as `score` checks them."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from skyvln_eval.errors import (
    AlteredGroundTruthError,
    DataError,
    ForeignRowsError,
    IncompleteRunError,
)
from skyvln_eval.harness import run_results
from skyvln_eval.metrics import read_results, write_results
from tests.conftest import make_record
from tests.metrics.helpers import result
from tests.reports.test_run_coverage import IDS, config, run_dir


@pytest.fixture
def two_splits(dataset_factory: Callable[..., Path]) -> Path:
    records = [make_record(route_index=e[6:]) for e in IDS]
    return dataset_factory({"val_seen": records, "val_unseen": records})


def test_keys_without_a_row_are_named_not_dropped(two_splits: Path, tmp_path: Path) -> None:
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:2])
    asked = [("val_seen", IDS[1]), ("val_seen", "1913__9_9"), ("val_unseen", IDS[0])]
    with pytest.raises(IncompleteRunError) as missing:
        run_results(run, asked)
    message = str(missing.value)
    assert "2 missing episode(s): val_seen/1913__9_9, val_unseen/1913__0_1" in message
    assert "Keys are (split, episode_id)" in message and "allow_incomplete=True" in message
    assert [r.episode_id for r in run_results(run, asked, allow_incomplete=True)] == [IDS[1]]
    # A row that only records the run stopping is no episode's result either.
    stopped = run_dir(
        tmp_path / "stopped", config(two_splits, limit=2), IDS[:2], **{IDS[1]: {"fatal": "401"}}
    )
    with pytest.raises(IncompleteRunError, match="1 of them have a row that only records"):
        run_results(stopped, [("val_seen", IDS[1])])


def test_an_episode_results_own_key_picks_it_and_a_bad_key_is_named(
    two_splits: Path, tmp_path: Path
) -> None:
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:2])
    rows = run_results(run)
    again = run_results(run, [r.key for r in reversed(rows)])  # (system, split, mode, id)
    assert [r.key for r in again] == [r.key for r in reversed(rows)]
    with pytest.raises(DataError, match=r"a key is \(split, episode_id\).*got 'val_seen'"):
        run_results(run, ["val_seen"])  # type: ignore[list-item]


def test_an_incomplete_run_says_what_to_pass_in_python(two_splits: Path, tmp_path: Path) -> None:
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:1])
    with pytest.raises(IncompleteRunError, match=r"allow_incomplete=True\) to score the 1"):
        run_results(run)


def test_a_folder_of_split_runs_reads_as_all_of_them(two_splits: Path, tmp_path: Path) -> None:
    # reproduce writes runs/<system>/<split>; `run_results(runs/full)` said "run config
    # runs/full/config.yaml: cannot read it".
    system = tmp_path / "runs" / "full"
    system.mkdir(parents=True)
    unseen = run_dir(
        system / "val_unseen", config(two_splits, splits=("val_unseen",), limit=1), IDS[:1]
    )
    rows_file = unseen / "results.jsonl"
    rows_file.write_text(
        rows_file.read_text().replace('"split": "val_seen"', '"split": "val_unseen"')
    )
    run_dir(system / "val_seen", config(two_splits, limit=2), IDS[:2])
    rows = run_results(system)
    assert [(r.split, r.episode_id) for r in rows] == [
        ("val_seen", IDS[0]),
        ("val_seen", IDS[1]),
        ("val_unseen", IDS[0]),
    ]
    assert [r.split for r in run_results(system, [("val_unseen", IDS[0])])] == ["val_unseen"]
    # Each is checked: an unfinished one refuses the lot.
    run_dir(system / "zz", config(two_splits, limit=3), IDS[:1])
    with pytest.raises(IncompleteRunError, match=f"run {system / 'zz'}"):
        run_results(system)
    # One level up holds folders of runs: they are named.
    with pytest.raises(DataError) as above:
        run_results(tmp_path / "runs")
    assert "its folders 'full' hold run directories" in str(above.value)
    with pytest.raises(DataError, match="pass its folder"):
        run_results(system / "val_seen" / "results.jsonl")


def test_damaged_lines_are_told_not_read_past_in_silence(two_splits: Path, tmp_path: Path) -> None:
    """A damaged row made its episode look never run (or, with allow_incomplete, left it
    out) without a word."""
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:2])
    results = run / "results.jsonl"
    lines = results.read_bytes().splitlines(keepends=True)
    results.write_bytes(b"".join(lines[:2]) + lines[2][:40] + b"\n")  # its second row cut
    with pytest.warns(UserWarning, match=r"results\.jsonl: 1 damaged line\(s\) read past \(line 3"):
        rows = run_results(run, allow_incomplete=True)
    assert [r.episode_id for r in rows] == [IDS[0]]
    with pytest.warns(UserWarning, match="counts as not run"), pytest.raises(IncompleteRunError):
        run_results(run)


def test_allowed_incomplete_or_asked_by_key_the_rows_are_still_checked(
    two_splits: Path, tmp_path: Path
) -> None:
    """An audit: a row whose ground truth was edited to the drone's last view (SR 0 -> 1),
    and rows another config made, were refused by run_results(run) but returned with
    allow_incomplete=True or keys=, where `score` refuses them either way."""
    run = run_dir(tmp_path / "run", config(two_splits, limit=3), IDS[:2])  # incomplete
    rows = read_results(run / "results.jsonl")
    goal = rows[1].gt_path_corners.copy()
    goal[-1] += 0.001  # the goal moved by about 100 m
    write_results(
        run / "results.jsonl", [rows[0], result(rows[1].visited_views, goal, episode_id=IDS[1])]
    )
    for ask in ({"allow_incomplete": True}, {"keys": [("val_seen", IDS[1])]}):
        with pytest.raises(AlteredGroundTruthError, match=f"run {run}: 1 row.*val_seen/{IDS[1]}"):
            run_results(run, **ask)  # type: ignore[arg-type]

    other = run_dir(tmp_path / "other", config(two_splits, limit=2, system="another"), IDS[:2])
    for ask in ({"allow_incomplete": True}, {"keys": [("val_seen", IDS[0])]}):
        with pytest.raises(ForeignRowsError, match="system 'agent', not 'another'"):
            run_results(other, **ask)  # type: ignore[arg-type]

    # Rows outside the run's selection are refused too; a missing one only without
    # allow_incomplete.
    beyond = run_dir(tmp_path / "beyond", config(two_splits, limit=1), IDS[:2])
    for ask in ({"allow_incomplete": True}, {"keys": [("val_seen", IDS[0])]}):
        with pytest.raises(IncompleteRunError, match=f"not in the run's selection.*{IDS[1]}"):
            run_results(beyond, **ask)  # type: ignore[arg-type]
    partial = run_dir(tmp_path / "partial", config(two_splits, limit=3), IDS[:2])
    assert len(run_results(partial, allow_incomplete=True)) == 2
    assert [r.episode_id for r in run_results(partial, [("val_seen", IDS[1])])] == [IDS[1]]


def test_unknown_coverage_is_refused_or_allowed_with_a_warning(
    two_splits: Path, tmp_path: Path
) -> None:
    gone = run_dir(tmp_path / "gone", config(tmp_path / "moved", limit=2), IDS[:2])
    for ask in ({}, {"keys": [("val_seen", IDS[0])]}):
        with pytest.raises(DataError, match=f"the data of run {gone}"):
            run_results(gone, **ask)  # type: ignore[arg-type]
    with pytest.warns(UserWarning, match=f"NOT CHECKED whether run {gone} is complete"):
        assert len(run_results(gone, allow_incomplete=True)) == 2


def test_a_key_of_another_system_or_mode_is_refused(two_splits: Path, tmp_path: Path) -> None:
    """An audit: ("SOME OTHER SYSTEM", "val_seen", "andh-full", id) returned the run's
    'agent'/'andh' row for that episode, the key's system and mode ignored."""
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:2])
    for key in [
        ("SOME OTHER SYSTEM", "val_seen", "andh", IDS[0]),
        ("agent", "val_seen", "andh-full", IDS[0]),
        ("agent", "val_seen", "andh-full", "1913__9_9"),  # no row: the run's rows say
    ]:
        with pytest.raises(DataError) as refused:
            run_results(run, [key], allow_incomplete=True)
        assert f"is of system {key[0]!r}, mode {key[2]!r}" in str(refused.value)
        assert "the run's rows are of system 'agent', mode 'andh'" in str(refused.value)
    assert [r.episode_id for r in run_results(run, [("agent", "val_seen", "andh", IDS[1])])] == [
        IDS[1]
    ]


def test_an_episode_whose_only_row_is_damaged_is_named_with_its_line_and_reason(
    two_splits: Path, tmp_path: Path
) -> None:
    """An audit: a row with status 'okay' made run_results say '1 missing episode(s) ...
    Finish it with skyvln-eval run', the line and reason only in a separate warning."""
    run = run_dir(tmp_path / "run", config(two_splits, limit=2), IDS[:2])
    results = run / "results.jsonl"
    lines = results.read_text().splitlines(keepends=True)
    lines[2] = lines[2].replace('"status": "ok"', '"status": "okay"')
    results.write_text("".join(lines))
    said = (
        f"1 of them have only a damaged row in {results}, read past (line 3, "
        f"val_seen/{IDS[1]}: not a valid row: status: must be one of ('ok', 'degraded', "
        "'error'), got 'okay')"
    )
    for keys in (None, [("val_seen", IDS[1])]):
        with pytest.warns(UserWarning), pytest.raises(IncompleteRunError) as refused:
            run_results(run, keys)
        assert f"1 missing episode(s): val_seen/{IDS[1]}. " in str(refused.value)
        assert said in str(refused.value)
    # Allowed incomplete, it counts as not run, as the warning says.
    with pytest.warns(UserWarning, match="line 3: not a valid row: status"):
        assert [r.episode_id for r in run_results(run, allow_incomplete=True)] == [IDS[0]]
