"""The closed-loop runner and its log: segments, determinism, columns, Parquet round trip."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from skyvln_eval.control import (
    LOG_COLUMNS,
    Command,
    Flight,
    fly_to,
    load_flight_log,
    log_frame,
    save_flight_log,
)
from skyvln_eval.control.closed_loop import _step_windows
from skyvln_eval.control.flight_log import SETTINGS_KEY
from skyvln_eval.errors import DataError, FormatVersionError
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim import DroneState, ScenarioSpec, make_scenario
from skyvln_eval.sim.reference import ReferenceConfig, ReferenceWindow, segment_reference
from tests.control.helpers import START, TARGET, controller, scenario

SECOND = ViewPose(4.0, 14.0, 15.0, -2.5)


def two_segments(name: str, seed: int = 0) -> tuple[Flight, list[pd.DataFrame]]:
    flight = Flight(controller(name), START, scenario=scenario("crossing", seed=2), seed=seed)
    logs = [flight.fly_to(TARGET, 40.0).log, flight.fly_to(SECOND, 40.0).log]
    return flight, logs


@pytest.mark.parametrize("name", ["nmpc", "mpc", "pid"])
def test_successive_segments_continue_time_state_and_obstacles(name: str) -> None:
    flight, (first, second) = two_segments(name)
    dt = flight.dt_s
    assert second.t_s.iloc[0] == pytest.approx(first.t_s.iloc[-1] + dt)
    assert np.allclose(np.diff(pd.concat([first, second]).t_s), dt)
    # The second segment starts where the first ended, with the obstacles where they are then.
    assert second.x_m.iloc[0] == pytest.approx(first.x_m.iloc[-1], abs=0.1)
    pd.testing.assert_frame_equal(flight.log(), pd.concat([first, second], ignore_index=True))
    assert np.linalg.norm(flight.state.position_m - [SECOND.x_m, SECOND.y_m, SECOND.z_m]) < 0.5


@pytest.mark.parametrize("name", ["nmpc", "pid"])
def test_runs_are_deterministic_given_their_seeds(name: str) -> None:
    _, a = two_segments(name, seed=4)
    _, b = two_segments(name, seed=4)
    timeless = [c for c in LOG_COLUMNS if c != "solve_time_ms"]
    for left, right in zip(a, b, strict=True):
        pd.testing.assert_frame_equal(left[timeless], right[timeless])


def test_the_log_has_the_agreed_columns_and_types() -> None:
    log = two_segments("nmpc")[0].log()
    assert list(log.columns[: len(LOG_COLUMNS)]) == list(LOG_COLUMNS)
    assert log.controller.unique().tolist() == ["nmpc"]
    assert log.scenario.unique().tolist() == ["crossing-2-seed2"]
    assert log.solve_failed.dtype == bool and log.collision.dtype == bool
    assert log.constraint_violation.dtype == bool and log.iterations.dtype == np.int64
    numeric = [c for c in LOG_COLUMNS if c not in ("controller", "scenario", "status")]
    assert np.isfinite(log[numeric].astype(float)).all().all()
    assert (log.solve_time_ms > 0).all() and (log.iterations > 0).all()
    assert set(log.status) <= {"solved", "solved_soft"}


def test_fly_to_is_one_segment_of_a_flight() -> None:
    final, log = fly_to(START, TARGET, controller("nmpc"), scenario("static"), t0_s=3.0)
    assert log.t_s.iloc[0] == pytest.approx(3.0)
    assert np.linalg.norm(final.position_m - [TARGET.x_m, TARGET.y_m, TARGET.z_m]) < 0.5
    assert (log.min_clearance_m >= 0).all()


def test_the_log_round_trips_through_parquet(tmp_path: Path) -> None:
    flight, _ = two_segments("mpc")
    log = flight.log()
    path = save_flight_log(log, tmp_path / "runs" / "flight.parquet", flight.controller.settings())
    again = load_flight_log(path)
    pd.testing.assert_frame_equal(again, log)
    assert again.attrs["settings"]["name"] == "mpc"
    assert again.attrs["settings"]["horizon_steps"] == 20
    assert [p.name for p in path.parent.iterdir()] == ["flight.parquet"]  # no temporary left


def test_an_empty_log_still_has_the_columns() -> None:
    assert list(log_frame([]).columns) == list(LOG_COLUMNS)


def test_the_log_fixes_each_columns_type_whatever_the_rows_hold(tmp_path: Path) -> None:
    row: dict[str, object] = dict.fromkeys(LOG_COLUMNS, 1)  # ints where floats belong
    row |= {"controller": "pid", "scenario": "none", "status": "ok", "iterations": 3.0}
    row |= {"solve_failed": 0, "collision": np.bool_(False), "constraint_violation": 1}
    log = log_frame([row, {**row, "t_s": 0.5}])
    kinds = {name: log[name].dtype.kind for name in LOG_COLUMNS}
    assert kinds["t_s"] == kinds["x_m"] == kinds["min_clearance_m"] == "f"
    assert kinds["iterations"] == "i" and kinds["collision"] == kinds["solve_failed"] == "b"
    assert str(log["controller"].dtype) == str(log["status"].dtype) == "str"
    again = load_flight_log(save_flight_log(log, tmp_path / "typed.parquet"))
    pd.testing.assert_frame_equal(again, log, check_exact=True)


def test_reading_something_else_is_a_clear_error(tmp_path: Path) -> None:
    other = tmp_path / "other.parquet"
    pq.write_table(pa.table({"a": [1]}), other)
    with pytest.raises(DataError, match="not a flight log"):
        load_flight_log(other)
    with pytest.raises(DataError, match="cannot read a flight log"):
        load_flight_log(tmp_path / "missing.parquet")
    with pytest.raises(DataError, match="column"):
        save_flight_log(pd.DataFrame({"t_s": [0.0]}), tmp_path / "bad.parquet")


@pytest.mark.parametrize(
    ("stored", "complaint"), [(b"[1, 2]", "not a JSON object"), (b"{", "not JSON")]
)
def test_stored_settings_that_are_not_an_object_are_a_clear_error(
    tmp_path: Path, stored: bytes, complaint: str
) -> None:
    # They were read as no settings: the readers then described the flight with defaults.
    path = save_flight_log(log_frame([]), tmp_path / "odd.parquet", {"controller": "nmpc"})
    table = pq.read_table(path)
    pq.write_table(
        table.replace_schema_metadata({**table.schema.metadata, SETTINGS_KEY: stored}), path
    )
    with pytest.raises(DataError, match=f"odd.parquet: its stored settings are {complaint}"):
        load_flight_log(path)


def test_a_log_of_another_format_version_says_what_to_do(tmp_path: Path) -> None:
    path = save_flight_log(log_frame([]), tmp_path / "old.parquet")
    table = pq.read_table(path)
    metadata = {**table.schema.metadata, b"skyvln_format_version": b"0"}
    pq.write_table(table.replace_schema_metadata(metadata), path)
    with pytest.raises(FormatVersionError, match="Record the run again"):
        load_flight_log(path)


def test_obstacles_added_per_segment_keep_moving_across_segments() -> None:
    # The replay-harness pattern: plan the segment, place obstacles against it, fly it.
    flight = Flight(controller("nmpc"), START, seed=3)
    for i, target in enumerate((TARGET, SECOND)):
        reference = flight.segment_reference(target)
        times = np.arange(flight.t_s, reference.end_time_s, 0.1)
        spec = ScenarioSpec(kind="crossing", n_obstacles=2, seed=10 + i)
        new = make_scenario(spec, times, reference.window(times).position_m)
        flight.scenario = flight.scenario.merged(new)
        result = flight.fly_to(target, reference=reference)
        assert result.reached and (result.log.min_clearance_m >= 0).all()
    assert len(flight.scenario.obstacles) == 4
    assert flight.log().scenario.iloc[-1] == "crossing-2-seed10+crossing-2-seed11"


def test_more_obstacles_than_slots_are_still_avoided() -> None:
    ctl = controller("nmpc", max_obstacles=2)
    flight = Flight(ctl, START, scenario=scenario("crossing", seed=5, n_obstacles=5))
    result = flight.fly_to(TARGET)
    # It got there, kept out of them, and they came close (or keeping out proved nothing).
    assert result.reached and (result.log.min_clearance_m >= 0).all()
    assert result.log.min_clearance_m.min() < 0.5


def test_a_long_segment_gets_the_time_it_needs_by_default() -> None:
    far = ViewPose(300.0, 0.0, 10.0, 0.0)  # 150 s at the default 2 m/s cruise speed
    result = Flight(controller("pid"), START).fly_to(far)
    assert result.reached and result.t_end_s > 150.0


def test_a_segment_to_where_the_drone_is_still_takes_a_control_step() -> None:
    # An audit: a move to the drone's own pose took 0 steps, so the next decision had the
    # same time as this one, and the viewer's decision timeline merged the two.
    flight = Flight(controller("pid"), START)
    here = ViewPose(START.x_m, START.y_m, START.z_m, START.yaw_rad)
    before = flight.t_s
    result = flight.fly_to(here)
    assert result.reached and len(result.rows) == 1
    assert result.t_end_s == pytest.approx(before + flight.dt_s)


def test_step_windows_come_in_growing_batches_with_the_steps_own_clock() -> None:
    # A flight asks for windows as it flies: one that arrives early has not paid for the
    # rest of the time it was allowed, and every window's times are the ones one batch of
    # all steps (each clock the previous one plus dt) would give, to the last bit.
    reference = segment_reference(START, TARGET, 0.3)
    offsets = 0.05 * np.arange(21)
    clock = [0.3]
    for _ in range(999):
        clock.append(clock[-1] + 0.05)
    whole = list(reference.windows(np.asarray(clock)[:, None] + offsets))
    asked: list[int] = []
    original = reference.windows

    def counting(times_s: np.ndarray) -> Iterator[ReferenceWindow]:
        asked.append(len(times_s))
        return original(times_s)

    object.__setattr__(reference, "windows", counting)
    lazy = _step_windows(reference, 0.3, 0.05, 1000, offsets)
    first = list(itertools.islice(lazy, 40))
    assert asked == [32, 64]  # 40 steps flown: two batches made, not 1000 steps' worth
    rest = list(lazy)
    assert asked == [32, 64, 128, 256, 512, 8] and len(first) + len(rest) == 1000
    for a, b in zip(first + rest, whole, strict=True):
        assert np.array_equal(a.times_s, b.times_s) and np.array_equal(a.states, b.states)
        assert np.array_equal(a.inputs, b.inputs) and np.array_equal(a.yaw_rad, b.yaw_rad)


def test_a_crash_ends_the_flight_where_it_happened() -> None:
    # PID flies straight through what is in its way: with stop_on_collision the segment
    # ends with the first step that touches an obstacle.
    obstacles = scenario("static", seed=1)
    on = Flight(controller("pid"), START, scenario=obstacles)
    crashed = on.fly_to(TARGET, 40.0, stop_on_collision=True)
    log = crashed.log
    assert crashed.collided and not crashed.reached
    assert log.collision.iloc[-1] and not log.collision.iloc[:-1].any()
    last = log.iloc[-1]
    assert on.t_s == pytest.approx(last.t_s + on.dt_s)
    flown_in_step_m = np.linalg.norm(on.state.position_m - [last.x_m, last.y_m, last.z_m])
    assert (
        flown_in_step_m <= np.linalg.norm([last.vx_m_s, last.vy_m_s, last.vz_m_s]) * on.dt_s + 0.1
    )
    # Without it the drone flies on through the obstacle to the target.
    through = Flight(controller("pid"), START, scenario=obstacles).fly_to(TARGET, 40.0)
    assert through.collided and len(through.log) > len(log)
    timeless = [c for c in LOG_COLUMNS if c != "solve_time_ms"]
    pd.testing.assert_frame_equal(through.log.iloc[: len(log)][timeless], log[timeless])


def test_a_non_finite_command_eases_to_hover_from_the_last_applied_input() -> None:
    pid = controller("pid")
    real_step, steps = pid.step, []

    def once_nan(*args: object) -> Command:
        command = real_step(*args)  # type: ignore[arg-type]
        steps.append(command)
        if len(steps) == 5:  # a controller bug: NaN once (and kept as its last input)
            pid.previous_input = np.full(3, np.nan)
            return Command(np.nan, np.nan, np.nan, command.yaw_ref_rad, command.stats)
        return command

    pid.step = once_nan  # type: ignore[method-assign]
    flight = Flight(pid, START)
    log = flight.fly_to(TARGET, 40.0).log
    fallback = log.iloc[4]
    assert fallback.status == "fallback_hover:non_finite_command" and fallback.solve_failed
    # Every number finite after it (the clearance is inf: no obstacles).
    text = ("controller", "scenario", "status", "min_clearance_m")
    numeric = [c for c in LOG_COLUMNS if c not in text]
    assert np.isfinite(log[numeric].astype(float).to_numpy()).all()
    assert np.isfinite(flight.state.position_m).all()


def test_the_nmpc_keeps_out_between_its_samples_at_speed() -> None:
    # At 12 m/s a step is 1.2 m, more than the obstacles' 1.4 m keep-out spheres leave a
    # sampled constraint to see: the controller widens its sampled radii by the step, so
    # the path over whole steps keeps out (the log measures clearance over each step).
    fast = ReferenceConfig(cruise_speed_m_s=12.0, max_acceleration_m_s2=4.0)
    start, target = DroneState(0.0, 0.0, 10.0), ViewPose(80.0, 0.0, 10.0, 0.0)
    reference = segment_reference(start, target, 0.0, fast)
    times = np.arange(0.0, reference.end_time_s, 0.1)
    spec = ScenarioSpec(kind="crossing", n_obstacles=2, seed=0)  # sampled only: -0.30 m
    obstacles = make_scenario(spec, times, reference.window(times).position_m)
    flight = Flight(controller("nmpc/riccati"), start, obstacles, reference_config=fast)
    log = flight.fly_to(target, 30.0).log
    assert log.min_clearance_m.min() < 0.5  # the obstacles were in the way
    assert (log.min_clearance_m >= 0.0).all() and not log.collision.any()


def test_controllers_of_one_problem_stepped_from_threads_fly_as_when_alone() -> None:
    """Controllers of one problem share its Functions (HPIPM's workspaces, the stats an
    interpreted solve reports): stepped from several threads, by any caller, they must
    not run them at once. Four flights at once, thread switches as often as Python allows,
    give the commands each gives alone (an audit measured up to 5.3 m/s^2 apart in thrust
    when only a flight's own lock kept the solves apart)."""
    import sys
    import threading

    timeless = [c for c in LOG_COLUMNS if c != "solve_time_ms"]

    def fly(seed: int) -> pd.DataFrame:
        flight = Flight(controller("nmpc"), START, scenario=scenario("crossing", seed=seed))
        return flight.fly_to(TARGET, 6.0).log[timeless]

    alone = [fly(seed) for seed in range(4)]
    together: dict[int, pd.DataFrame] = {}
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [
            threading.Thread(target=lambda s=seed: together.__setitem__(s, fly(s)))
            for seed in range(4)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(interval)
    for seed in range(4):
        pd.testing.assert_frame_equal(together[seed], alone[seed])
