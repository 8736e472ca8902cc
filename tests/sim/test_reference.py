"""References from a target pose: endpoints, speed and acceleration limits, yaw, feed-forward."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import ViewPose
from skyvln_eval.sim import DroneState, ReferenceConfig, segment_reference

G = 9.81


@pytest.mark.parametrize("distance_m", [0.5, 3.0, 40.0])
def test_segment_starts_here_ends_on_target_at_rest_within_limits(distance_m: float) -> None:
    config = ReferenceConfig(cruise_speed_m_s=2.0, max_acceleration_m_s2=1.0)
    start = DroneState(5.0, 5.0, 20.0, yaw_rad=0.3)
    target = ViewPose(5.0 + distance_m * 0.6, 5.0 + distance_m * 0.8, 20.0, 0.3)
    reference = segment_reference(start, target, 10.0, config)
    dt = 0.01
    times = np.arange(9.0, reference.end_time_s + 1.0, dt)
    window = reference.window(times)
    assert np.allclose(window.position_m[0], start.position_m)
    assert np.allclose(window.position_m[-1], [target.x_m, target.y_m, target.z_m])
    assert np.allclose(window.velocity_m_s[[0, -1]], 0.0)
    speed = np.linalg.norm(window.velocity_m_s, axis=1)
    assert speed.max() <= config.cruise_speed_m_s + 1e-9
    # Velocity is the derivative of position; acceleration stays under its limit.
    numeric = np.diff(window.position_m, axis=0) / dt
    assert np.allclose(numeric, (window.velocity_m_s[1:] + window.velocity_m_s[:-1]) / 2, atol=1e-3)
    acceleration = np.linalg.norm(np.diff(window.velocity_m_s, axis=0) / dt, axis=1)
    assert acceleration.max() <= config.max_acceleration_m_s2 + 1e-3


def test_long_segments_cruise_at_the_cruise_speed() -> None:
    reference = segment_reference(DroneState(0, 0, 10), ViewPose(100, 0, 10, 0.0), 0.0)
    window = reference.window(np.array([reference.end_time_s / 2]))
    assert np.linalg.norm(window.velocity_m_s[0]) == pytest.approx(2.0)


def test_reference_inputs_are_hover_at_rest_and_lean_into_acceleration() -> None:
    reference = segment_reference(DroneState(0, 0, 10), ViewPose(20, 0, 10, 0.0), 0.0)
    window = reference.window(np.array([-1.0, 1.0, reference.end_time_s + 1.0]))
    assert np.allclose(window.inputs[0], [G, 0, 0])
    assert np.allclose(window.inputs[2], [G, 0, 0])
    assert window.states[1, 7] > 0.0  # pitching forward to accelerate east
    assert window.inputs[1, 2] == pytest.approx(window.states[1, 7] / 0.78)


def test_yaw_turns_the_short_way_to_the_target_heading() -> None:
    start = DroneState(0, 0, 10, yaw_rad=math.radians(170))
    target = ViewPose(0, 0, 10, math.radians(-160))
    reference = segment_reference(start, target, 0.0)
    times = np.linspace(0.0, reference.end_time_s, 50)
    yaws = np.unwrap(reference.window(times).yaw_rad)
    assert np.all(np.diff(yaws) >= 0)  # counter-clockwise through 180 degrees
    assert yaws[-1] - yaws[0] == pytest.approx(math.radians(30))
    assert reference.end_time_s > 0.0  # turning on the spot takes time


def test_bad_reference_settings_name_the_field() -> None:
    with pytest.raises(ConfigError, match="cruise_speed_m_s"):
        ReferenceConfig(cruise_speed_m_s=0.0)


def test_windows_of_many_steps_equal_each_steps_window_bit_for_bit() -> None:
    # The flight loop takes every step's window from one batch: it must be the same floats.
    start = DroneState(x_m=10.0, y_m=20.0, z_m=100.0, yaw_rad=0.3)
    reference = segment_reference(start, ViewPose(260.0, -40.0, 120.0, -2.5), t0_s=3.7)
    dt, clock = 0.1, [3.7]
    for _ in range(399):
        clock.append(clock[-1] + dt)
    times = np.asarray(clock)[:, None] + dt * np.arange(21)
    for k, window in enumerate(reference.windows(times)):
        alone = reference.window(clock[k] + dt * np.arange(21))
        for name in ("times_s", "states", "inputs", "yaw_rad"):
            assert np.array_equal(getattr(window, name), getattr(alone, name)), (k, name)
