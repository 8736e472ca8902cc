"""Closed-loop behaviour of NMPC, linear MPC and PID: tracking, limits, clearance."""

from __future__ import annotations

import numpy as np
import pytest

from skyvln_eval.control import LOG_COLUMNS, Flight
from skyvln_eval.sim import DroneState, PlantConfig, ReferenceTrajectory, WindConfig
from tests.control.helpers import START, TARGET, controller, scenario

MPCS = ["nmpc", "mpc", "nmpc/riccati", "mpc/riccati"]
ALL = [*MPCS, "pid"]


@pytest.mark.parametrize("name", ALL)
def test_tracking_without_obstacles_converges(name: str) -> None:
    flight = Flight(controller(name), START)
    result = flight.fly_to(TARGET, max_time_s=40.0)
    assert result.reached
    final = result.final_state
    assert np.linalg.norm(final.position_m - [TARGET.x_m, TARGET.y_m, TARGET.z_m]) < 0.1
    assert abs(final.yaw_rad - TARGET.yaw_rad) < 0.05
    assert result.failed_steps == 0
    assert list(result.log.columns[: len(LOG_COLUMNS)]) == list(LOG_COLUMNS)
    assert np.isinf(result.log["min_clearance_m"]).all()


@pytest.mark.parametrize("name", MPCS)
def test_mpcs_track_the_reference_closely(name: str) -> None:
    log = Flight(controller(name), START).fly_to(TARGET, 40.0).log
    error = np.hypot(np.hypot(log.x_m - log.ref_x_m, log.y_m - log.ref_y_m), log.z_m - log.ref_z_m)
    assert float(np.sqrt(np.mean(error**2))) < 0.1


def step_reference(goal: tuple[float, float, float]) -> ReferenceTrajectory:
    """A step: the reference jumps to ``goal`` at once and stays there."""

    def path(times: np.ndarray) -> tuple[np.ndarray, ...]:
        zeros = np.zeros((len(times), 3))
        return np.tile(goal, (len(times), 1)), zeros, zeros

    return ReferenceTrajectory(path, lambda times: np.full(len(times), 2.0), 0.0)


@pytest.mark.parametrize("name", ALL)
def test_every_input_bound_and_rate_limit_holds_on_every_step(name: str) -> None:
    # A step of 30 m sideways and 15 m up drives every input into its limits.
    ctl = controller(name)
    flight = Flight(ctl, DroneState(0, 0, 10), scenario=scenario("crossing"))
    log = flight.fly(step_reference((30.0, -20.0, 25.0)), duration_s=15.0).log
    limits = ctl.limits
    tilt = log[["cmd_roll_rad", "cmd_pitch_rad"]].to_numpy()
    applied = np.vstack([[0.0, 0.0], tilt[:-1]])  # the hover input before the first step
    eps = 1e-9
    assert (log.cmd_thrust_m_s2 >= limits.thrust_min_m_s2 - eps).all()
    assert (log.cmd_thrust_m_s2 <= limits.thrust_max_m_s2 + eps).all()
    assert (np.abs(tilt) <= limits.tilt_ref_max_rad + eps).all()
    assert (np.abs(tilt - applied) <= limits.tilt_ref_step_max_rad + eps).all()
    assert not log.constraint_violation.any() or name == "pid"
    # The limits were reached, so the checks above were not vacuous.
    assert np.abs(tilt).max() > 0.99 * limits.tilt_ref_max_rad
    assert np.abs(np.diff(tilt, axis=0)).max() > 0.99 * limits.tilt_ref_step_max_rad
    # PID caps its speed set-point, so it climbs without saturating the thrust (and its
    # thrust holds the vertical loop's part at the tilt it has: no more when cut).
    thrust_reached = 0.99 * limits.thrust_max_m_s2 if name != "pid" else 1.3 * 9.81
    assert log.cmd_thrust_m_s2.max() > thrust_reached


@pytest.mark.parametrize("name", MPCS)
@pytest.mark.parametrize("kind", ["static", "crossing", "approaching", "spline"])
def test_clearance_stays_at_or_above_zero(name: str, kind: str) -> None:
    flight = Flight(controller(name), START, scenario=scenario(kind, seed=1))
    result = flight.fly_to(TARGET, max_time_s=40.0)
    log = result.log
    assert (log.min_clearance_m >= 0.0).all(), log.min_clearance_m.min()
    assert not log.collision.any()
    assert not log.constraint_violation.any()
    assert result.reached
    # The obstacles were in the way: the constraint was active at some point.
    assert log.min_clearance_m.min() < 0.2


def test_pid_knows_nothing_of_obstacles() -> None:
    log = Flight(controller("pid"), START, scenario=scenario("static", seed=1)).fly_to(TARGET).log
    assert log.min_clearance_m.min() < 0.0
    assert log.constraint_violation.any()


@pytest.mark.parametrize("name", ALL)
def test_flies_in_wind_and_sensor_noise(name: str) -> None:
    from skyvln_eval.sim import SensorNoise

    config = PlantConfig(
        wind=WindConfig(mean_m_s=(1.0, -0.5, 0.0), gust_std_m_s=0.3),
        noise=SensorNoise(position_std_m=0.02, velocity_std_m_s=0.02, attitude_std_rad=0.005),
    )
    flight = Flight(controller(name), START, plant_config=config, seed=5)
    result = flight.fly_to(TARGET, max_time_s=60.0)
    assert (
        np.linalg.norm(result.final_state.position_m - [TARGET.x_m, TARGET.y_m, TARGET.z_m]) < 0.5
    )
    assert result.failed_steps == 0


def test_the_pid_keeps_the_vertical_loop_when_the_tilt_is_cut() -> None:
    # An audit: with the tilt at its limit, the thrust was the asked force's norm, whose
    # horizontal excess went into the climb (19 km of altitude under velocity noise).
    import math

    from skyvln_eval.control.pid import PidController
    from skyvln_eval.frames import ViewPose
    from skyvln_eval.sim.obstacles import ObstacleForecast
    from skyvln_eval.sim.reference import ReferenceConfig, segment_reference

    pid = PidController()
    # 10 m/s above a hover reference 20 m east: descend, and tilt east as far as allowed.
    climbing = DroneState(0, 0, 100, vz_m_s=10.0)
    window = segment_reference(
        DroneState(20, 0, 100), ViewPose(20, 0, 100, 0.0), 0.0, ReferenceConfig()
    ).window(np.array([0.0]))
    for _ in range(30):
        command = pid.step(climbing, window, ObstacleForecast.none(np.array([0.0])))
    tilt = command.pitch_ref_rad * pid.params.pitch_gain
    assert command.pitch_ref_rad == pytest.approx(pid.limits.tilt_ref_max_rad)  # cut
    vertical = command.thrust_m_s2 * math.cos(tilt) * math.cos(command.roll_ref_rad)
    assert vertical < pid.params.gravity_m_s2  # it descends, as its z loop asks
