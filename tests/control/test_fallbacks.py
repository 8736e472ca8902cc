"""A failed, infeasible or non-finite step never raises: it falls back, flags and counts."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from skyvln_eval.control import Flight
from skyvln_eval.control.mpc import MpcController
from skyvln_eval.control.stage_qp import NZ
from skyvln_eval.errors import ConfigError
from skyvln_eval.sim import (
    ConstantVelocity,
    DroneState,
    ObstacleForecast,
    ObstacleScenario,
    SphereObstacle,
    segment_reference,
)
from tests.control.helpers import START, TARGET, controller

G = 9.81


def window_and_forecast(ctl: MpcController | object, t_s: float = 0.0):  # type: ignore[no-untyped-def]
    n = getattr(ctl, "horizon_steps", 0)
    times = t_s + 0.1 * np.arange(n + 1)
    reference = segment_reference(START, TARGET, 0.0)
    return reference.window(times), ObstacleForecast.none(times)


@pytest.mark.parametrize("name", ["nmpc", "mpc"])
def test_start_inside_an_obstacle_is_flown_out_without_an_exception(name: str) -> None:
    # The drone starts 0.3 m from the centre of a sphere it must keep 0.7 m from.
    sphere = SphereObstacle(ConstantVelocity((0.3, 0.0, 10.0)), radius_m=0.4, safety_radius_m=0.3)
    flight = Flight(controller(name), START, scenario=ObstacleScenario("inside", (sphere,)))
    result = flight.fly_to(TARGET, max_time_s=40.0)
    log = result.log
    assert log.min_clearance_m.iloc[0] < 0.0
    assert log.status.iloc[0] == "solved_soft"  # the slack let the solver find the way out
    outside = np.flatnonzero(log.min_clearance_m.to_numpy() >= 0.0)
    assert outside.size and (log.min_clearance_m.iloc[outside[0] :] >= 0.0).all()
    assert outside[0] < 20  # out within two seconds
    assert result.reached


@pytest.mark.parametrize("name", ["nmpc", "mpc", "pid"])
def test_a_non_finite_state_gives_a_finite_flagged_command(name: str) -> None:
    ctl = controller(name)
    window, forecast = window_and_forecast(ctl)
    good = ctl.step(START, window, forecast)
    assert not good.stats.failed
    for bad in (DroneState(math.nan, 0.0, 10.0), DroneState(0.0, 0.0, 10.0, vx_m_s=math.inf)):
        command = ctl.step(bad, window, forecast)
        assert command.is_finite()
        assert command.stats.failed
        assert command.stats.status.endswith("invalid_input")
    assert ctl.failures == 2


@pytest.mark.parametrize("name", ["nmpc", "mpc"])
def test_a_non_finite_reference_state_or_input_is_refused(name: str) -> None:
    ctl = controller(name)
    window, forecast = window_and_forecast(ctl)
    n = ctl.horizon_steps
    for field, row in (("states", 0), ("states", n), ("inputs", n - 1)):
        bad = dataclasses.replace(window, **{field: getattr(window, field).copy()})
        getattr(bad, field)[row, -1] = math.nan
        command = ctl.step(START, bad, forecast)
        assert command.is_finite() and command.stats.status.endswith("invalid_input")
    # The input past the horizon's last interval is not used, nor checked.
    unused = dataclasses.replace(window, inputs=window.inputs.copy())
    unused.inputs[n] = math.nan
    assert not ctl.step(START, unused, forecast).stats.failed


def test_a_non_finite_forecast_is_refused_without_an_exception() -> None:
    ctl = controller("nmpc")
    window, _ = window_and_forecast(ctl)
    times = window.times_s
    forecast = ObstacleForecast(
        times, np.full((1, len(times), 3), np.nan), np.array([0.4]), np.array([0.3])
    )
    command = ctl.step(START, window, forecast)
    assert command.is_finite() and command.stats.failed


def test_failed_solves_fall_back_to_the_shifted_plan_then_hover() -> None:
    ctl = controller("nmpc")
    assert isinstance(ctl, MpcController)
    window, forecast = window_and_forecast(ctl)
    state = DroneState(0.0, 0.0, 10.0)
    ctl.step(state, window, forecast)  # a good plan to fall back on
    plan = ctl._plan.copy()  # type: ignore[union-attr]

    def broken(shift: bool) -> tuple[bool, int]:
        ctl.rti.w[:] = np.nan
        return False, 50

    ctl.rti.solve = broken  # type: ignore[method-assign]
    statuses, commands = [], []
    for _ in range(ctl.horizon_steps + 3):
        command = ctl.step(state, window, forecast)
        statuses.append(command.stats.status)
        commands.append(command.inputs)
        assert command.is_finite() and command.stats.failed
    n = ctl.horizon_steps
    assert statuses[: n - 1] == ["fallback_shift"] * (n - 1)
    assert set(statuses[n - 1 :]) == {"fallback_hover"}
    stage = ctl.qp.stage
    assert np.allclose(commands[0], plan[stage + NZ : stage + NZ + 3])  # the plan's next input
    assert np.allclose(commands[-1], [G, 0.0, 0.0])  # eased back to hover
    assert ctl.failures == n + 3


def test_a_flight_with_a_broken_solver_keeps_flying_and_counts_failures() -> None:
    ctl = controller("nmpc")
    assert isinstance(ctl, MpcController)
    calls = {"n": 0}
    solve = ctl.rti.solve

    def flaky(shift: bool) -> tuple[bool, int]:
        calls["n"] += 1
        if calls["n"] % 7 == 0:
            return False, 50
        return solve(shift)

    ctl.rti.solve = flaky  # type: ignore[method-assign]
    result = Flight(ctl, START).fly_to(TARGET, max_time_s=40.0)
    assert result.reached
    assert result.failed_steps == int(result.log.solve_failed.sum()) > 0
    assert ctl.failures == result.failed_steps
    assert set(result.log.status[result.log.solve_failed]) == {"fallback_shift"}


def test_a_too_short_reference_window_is_a_clear_error() -> None:
    ctl = controller("nmpc")
    times = 0.1 * np.arange(5)
    window = segment_reference(START, TARGET, 0.0).window(times)
    with pytest.raises(ConfigError, match="needs the reference and the obstacle forecast at 21"):
        ctl.step(START, window, ObstacleForecast.none(times))


def test_after_fallbacks_the_warm_start_is_shifted_to_now() -> None:
    ctl = controller("nmpc")
    assert isinstance(ctl, MpcController)
    window, forecast = window_and_forecast(ctl)
    ctl.step(START, window, forecast)
    plan = ctl._plan.copy()  # type: ignore[union-attr]
    solve = ctl.rti.solve
    ctl.rti.solve = lambda shift: (False, 0)  # type: ignore[method-assign]
    ctl.step(START, window, forecast)
    ctl.step(START, window, forecast)  # two fallbacks: now is three steps after the plan
    ctl.rti.solve = solve  # type: ignore[method-assign]
    assert not ctl._warm_start(START.position_m)  # the guess is prepared in Python
    stage = ctl.qp.stage
    assert np.allclose(ctl.rti.guess[stage : 2 * stage], plan[4 * stage : 5 * stage])
    # With no fallback pending, the step Function shifts the plan itself.
    command = ctl.step(START, window, forecast)
    assert not command.stats.failed
    assert ctl._warm_start(START.position_m + np.array([1.0, 0.0, 0.0]))
    assert np.allclose(ctl.rti.warm[:3], [-1.0, 0.0, 0.0])


def test_a_solver_that_raises_is_a_failed_step_not_a_crash() -> None:
    ctl = controller("mpc")
    assert isinstance(ctl, MpcController)
    window, forecast = window_and_forecast(ctl)

    def crashing(shift: bool) -> tuple[bool, int]:
        raise RuntimeError("hpipm: internal error")

    ctl.rti.solve = crashing  # type: ignore[method-assign]
    command = ctl.step(START, window, forecast)
    assert command.is_finite() and command.stats.status == "fallback_hover"
    assert ctl.failures == 1
