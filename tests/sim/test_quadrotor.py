"""The paper's model: conventions, symbolic vs float, feed-forward inversion, config errors."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from skyvln_eval.errors import ConfigError
from skyvln_eval.sim import DroneState, InputLimits, QuadrotorParams, model_rhs, rk4_symbolic
from skyvln_eval.sim.quadrotor import attitude_for_acceleration, hover_input
from tests.conftest import REPO

PARAMS = QuadrotorParams()


def test_hover_is_an_equilibrium() -> None:
    x = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert np.allclose(model_rhs(x, hover_input(PARAMS), PARAMS), 0.0)


def test_positive_pitch_accelerates_east_and_positive_roll_south() -> None:
    pitched = model_rhs([0, 0, 0, 0, 0, 0, 0.0, 0.2], [PARAMS.gravity_m_s2, 0, 0.2], PARAMS)
    rolled = model_rhs([0, 0, 0, 0, 0, 0, 0.2, 0.0], [PARAMS.gravity_m_s2, 0.2, 0], PARAMS)
    assert pitched[3] > 0 and abs(pitched[4]) < 1e-12
    assert rolled[4] < 0 and abs(rolled[3]) < 1e-12


def test_attitude_follows_the_first_order_model() -> None:
    x = [0, 0, 0, 0, 0, 0, 0.1, -0.05]
    u = [PARAMS.gravity_m_s2, 0.3, 0.2]
    derivative = model_rhs(x, u, PARAMS)
    assert derivative[6] == pytest.approx((0.75 * 0.3 - 0.1) / 0.257)
    assert derivative[7] == pytest.approx((0.78 * 0.2 + 0.05) / 0.259)


def test_symbolic_rk4_agrees_with_the_float_model() -> None:
    step = rk4_symbolic(PARAMS, 0.1)
    x = np.array([0.0, 0.0, 5.0, 1.0, -0.5, 0.2, 0.1, -0.1])
    u = np.array([11.0, -0.2, 0.3])
    # Reference: the float model integrated finely with Euler steps.
    y = x.copy()
    for _ in range(10_000):
        y = y + 1e-5 * np.array(model_rhs(list(y), list(u), PARAMS))
    assert np.allclose(np.asarray(step(x, u)).ravel(), y, atol=1e-4)


def test_drag_acts_on_air_relative_velocity() -> None:
    x = [0, 0, 0, 2.0, 0, 0, 0, 0]
    still = model_rhs(x, hover_input(PARAMS), PARAMS)
    tailwind = model_rhs(x, hover_input(PARAMS), PARAMS, (2.0, 0.0, 0.0))
    assert still[3] == pytest.approx(-0.2)
    assert tailwind[3] == pytest.approx(0.0)


def test_feed_forward_attitude_produces_the_asked_acceleration() -> None:
    wanted = np.array([0.8, -1.2, 0.5])
    velocity = np.array([2.0, 1.0, -0.5])
    thrust, roll, pitch = attitude_for_acceleration(wanted, velocity, PARAMS)
    x = [0, 0, 0, *velocity, roll, pitch]
    derivative = model_rhs(x, [thrust, roll / 0.75, pitch / 0.78], PARAMS)
    assert np.allclose(derivative[3:6], wanted)
    assert np.allclose(derivative[6:8], 0.0)  # steady state: roll = K roll_ref


def test_drone_state_round_trips_through_the_model_vector() -> None:
    state = DroneState(1, 2, 3, 4, 5, 6, 0.1, 0.2, 0.3)
    again = DroneState.from_model_vector(state.model_vector(), state.yaw_rad)
    assert again == state
    assert all(type(v) is float for v in (again.x_m, again.vz_m_s, again.yaw_rad))
    assert not DroneState(math.nan, 0, 0).is_finite()
    assert not DroneState(0, 0, 0, yaw_rad=math.inf).is_finite()
    with pytest.raises(ValueError):
        DroneState.from_model_vector([1.0, 2.0, 3.0], 0.0)


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: QuadrotorParams(roll_time_constant_s=0.0), "roll_time_constant_s"),
        (lambda: QuadrotorParams(drag_x_1_s=-1.0), "drag_x_1_s"),
        (lambda: InputLimits(thrust_min_m_s2=12.0, thrust_max_m_s2=10.0), "thrust_max_m_s2"),
        (lambda: InputLimits(tilt_ref_max_rad=2.0), "tilt_ref_max_rad"),
        (lambda: InputLimits(tilt_ref_step_max_rad=math.nan), "tilt_ref_step_max_rad"),
    ],
)
def test_bad_parameters_name_the_field(make: object, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        make()  # type: ignore[operator]


def test_importing_the_simulation_does_not_import_casadi() -> None:
    code = "import sys, skyvln_eval.sim\nprint('casadi' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "False"
