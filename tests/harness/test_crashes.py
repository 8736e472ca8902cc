"""A crash in dynamics mode ends the episode where it happened, and the run says so."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from skyvln_eval.avdn import load_split
from skyvln_eval.control import load_flight_log
from skyvln_eval.frames import view_to_pose
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.commands import describe_report
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import read_results

MakeConfig = Callable[..., RunConfig]


def test_a_crash_ends_the_episode_where_it_happened_and_the_run_counts_it(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # PID does not avoid obstacles: at cruise speed through two crossing ones it hits some.
    obstacles = {"kind": "crossing", "n_obstacles": 2, "radius_m": 1.0, "safety_radius_m": 0.5}
    dynamics = {
        "controller": "pid",
        "controller_settings": {},
        "cruise_speed_m_s": 12.0,
        "obstacles": obstacles,
    }
    config = small_config(mode="dynamics", splits=("val_seen",), limit=4, dynamics=dynamics)
    report = run(config, tmp_path / "run")
    rows = read_results(tmp_path / "run" / RESULTS_FILE)
    georefs = {r.episode_id: r.georef for r in load_split(config.data, "val_seen").records}
    crashed = [r for r in rows if r.control is not None and r.control.collided]
    assert crashed, "the PID hit nothing: the test needs a crash"
    for row in crashed:
        assert row.extra["stop_reason"] == "collision"
        log = load_flight_log(tmp_path / "run" / str(row.control_log))
        # The flight ended with its first step that touched an obstacle, and the last
        # view is seen from there (its centre below the drone, within the step's 1.2 m at
        # 12 m/s), not from the segment's target.
        assert log.collision.iloc[-1] and log.collision.sum() == 1
        seen_from = view_to_pose(row.visited_views[-1], georefs[row.episode_id])
        crash = log.iloc[-1]
        assert np.hypot(seen_from.x_m - crash.x_m, seen_from.y_m - crash.y_m) < 1.5
    assert report.flights == {
        "flown": len(rows),
        "crashed": len(crashed),
        "with failed solves": sum(r.control.solve_failures > 0 for r in rows if r.control),
        "with segments cut short": 0,  # a crash's segment ends in the crash, not its time
    }
    # The PID's 5 m/s cap against a 12 m/s reference is said, not left to be found.
    assert any("pid's max_speed_m_s 5 is below the cruise speed 12 m/s" in n for n in report.notes)
    line = (
        f"flown: {len(rows)} episode(s), {len(crashed)} crashed (a step that touched an obstacle)"
    )
    assert any(text.startswith(line) for text in describe_report(report))
