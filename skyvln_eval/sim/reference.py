"""Time-parametrised references: from the current pose to a target pose at a cruise speed.

A :class:`ReferenceTrajectory` gives, for any times, the reference model state
``[p, v, roll, pitch]``, the reference inputs ``[T, roll_ref, pitch_ref]`` and the reference
yaw. Position, velocity and acceleration come from a path; attitude and inputs are their
steady-state feed-forward through the model (hover thrust ``g`` when not accelerating), see
:func:`~skyvln_eval.sim.quadrotor.attitude_for_acceleration`.

:func:`segment_reference` is what an agent action becomes in "dynamics" mode: a straight line
from the current position to the target waypoint and altitude, flown with a smooth speed
profile (sinusoidal acceleration up to ``max_acceleration_m_s2``, cruise at
``cruise_speed_m_s``, symmetric deceleration) while the heading turns smoothly to the target.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.frames import ViewPose, wrap_angle_rad
from skyvln_eval.sim.quadrotor import NX, DroneState, QuadrotorParams, require_positive

#: ``t -> (position, velocity, acceleration)``, each of shape ``(n, 3)`` for ``n`` times.
PathFunction = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], ...]]
YawFunction = Callable[[NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class ReferenceConfig:
    """How a target pose becomes a reference: speeds and acceleration limits."""

    cruise_speed_m_s: float = 2.0
    max_acceleration_m_s2: float = 1.0
    yaw_rate_max_rad_s: float = 0.5

    def __post_init__(self) -> None:
        require_positive(self, "cruise_speed_m_s", "max_acceleration_m_s2", "yaw_rate_max_rad_s")


@dataclass(frozen=True)
class ReferenceWindow:
    """The reference at ``n`` times: states ``(n, 8)``, inputs ``(n, 3)``, yaw ``(n,)``."""

    times_s: NDArray[np.float64]
    states: NDArray[np.float64]
    inputs: NDArray[np.float64]
    yaw_rad: NDArray[np.float64]

    @property
    def position_m(self) -> NDArray[np.float64]:
        return self.states[:, 0:3]

    @property
    def velocity_m_s(self) -> NDArray[np.float64]:
        return self.states[:, 3:6]


@dataclass(frozen=True)
class ReferenceTrajectory:
    """A reference defined by a path function and a yaw function, ending at ``end_time_s``."""

    path: PathFunction
    yaw: YawFunction
    end_time_s: float
    params: QuadrotorParams = field(default_factory=QuadrotorParams)

    def window(self, times_s: NDArray[np.float64]) -> ReferenceWindow:
        """The reference at each of ``times_s`` (held at the ends outside the path's span)."""
        times = np.asarray(times_s, dtype=np.float64)
        position, velocity, acceleration = self.path(times)
        p = self.params
        drag = np.array([p.drag_x_1_s, p.drag_y_1_s, p.drag_z_1_s])
        # Feed-forward: thrust vector f = a + g e3 + A v; T = |f|, roll and pitch its direction.
        force = acceleration + drag * velocity
        force[:, 2] += p.gravity_m_s2
        thrust = np.linalg.norm(force, axis=1)
        roll = np.arcsin(np.clip(-force[:, 1] / thrust, -1.0, 1.0))
        pitch = np.arctan2(force[:, 0], force[:, 2])
        states = np.empty((len(times), NX))
        states[:, 0:3] = position
        states[:, 3:6] = velocity
        states[:, 6] = roll
        states[:, 7] = pitch
        inputs = np.stack([thrust, roll / p.roll_gain, pitch / p.pitch_gain], axis=1)
        return ReferenceWindow(times, states, inputs, self.yaw(times))

    def windows(self, times_s: NDArray[np.float64]) -> Iterator[ReferenceWindow]:
        """:meth:`window` at each row of ``times_s`` ``(steps, n)``, computed as one batch
        (every operation is elementwise or per row, so the values are the same) and handed
        out one step at a time (a flight that arrives early takes only what it flies)."""
        steps, n = times_s.shape
        whole = self.window(times_s.reshape(-1))
        states = whole.states.reshape(steps, n, -1)
        inputs = whole.inputs.reshape(steps, n, -1)
        yaw = whole.yaw_rad.reshape(steps, n)
        for k in range(steps):
            yield ReferenceWindow(times_s[k], states[k], inputs[k], yaw[k])


def _clip(values: NDArray[np.float64], low: float, high: float) -> NDArray[np.float64]:
    """``np.clip`` for these short arrays without its per-call overhead (same values)."""
    return np.minimum(np.maximum(values, low), high)


def _speed_profile(
    length_m: float, cruise_m_s: float, accel_m_s2: float
) -> tuple[float, Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], ...]]]:
    """Distance, speed and acceleration along a path of ``length_m`` over time from its start.

    The speed rises as ``v_c (1 - cos(pi t / t_a)) / 2`` (peak acceleration ``accel_m_s2``),
    cruises, and falls symmetrically; a path too short to reach ``cruise_m_s`` uses the
    largest speed that fits. Returns the duration and ``tau -> (s, s', s'')``.
    """
    if length_m <= 0.0:
        return 0.0, lambda tau: (np.zeros_like(tau), np.zeros_like(tau), np.zeros_like(tau))
    v_c = min(cruise_m_s, math.sqrt(2.0 * accel_m_s2 * length_m / math.pi))
    t_a = math.pi * v_c / (2.0 * accel_m_s2)
    t_c = max(0.0, (length_m - v_c * t_a) / v_c)
    duration = 2.0 * t_a + t_c

    def ramp(tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        held = _clip(tau, 0.0, t_a)
        phase = np.pi * held / t_a
        s = v_c / 2.0 * (held - t_a / np.pi * np.sin(phase))
        return s, v_c / 2.0 * (1.0 - np.cos(phase)), accel_m_s2 * np.sin(phase)

    def distance(tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """Distance, speed and acceleration from the start, valid up to half the duration."""
        s, v, a = ramp(tau)
        return s + _clip(tau - t_a, 0.0, t_c) * v_c, v, a

    def profile(tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        tau = _clip(tau, 0.0, duration)
        s_up, v_up, a_up = distance(tau)
        s_down, v_down, a_down = distance(duration - tau)  # the same, run backwards
        rising = tau <= duration / 2.0
        return (
            np.where(rising, s_up, length_m - s_down),
            np.where(rising, v_up, v_down),
            np.where(rising, a_up, -a_down),
        )

    return duration, profile


def segment_reference(
    start: DroneState,
    target: ViewPose,
    t0_s: float,
    config: ReferenceConfig | None = None,
    params: QuadrotorParams | None = None,
) -> ReferenceTrajectory:
    """The reference from the current state to ``target`` (ENU waypoint, height, heading).

    Starts at ``t0_s`` from the current position, flies the straight line with the smooth
    speed profile and turns the heading along the shortest way, both ending at rest and on
    target; after that the reference holds the target (hover).
    """
    config = config or ReferenceConfig()
    origin = start.position_m
    delta = np.array([target.x_m, target.y_m, target.z_m]) - origin
    length = float(np.linalg.norm(delta))
    direction = delta / length if length > 0.0 else np.zeros(3)
    duration, profile = _speed_profile(
        length, config.cruise_speed_m_s, config.max_acceleration_m_s2
    )

    def path(times: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        s, v, a = profile(times - t0_s)
        return (
            origin + s[:, None] * direction,
            v[:, None] * direction,
            a[:, None] * direction,
        )

    turn = wrap_angle_rad(target.yaw_rad - start.yaw_rad)
    # Smoothstep 3x^2 - 2x^3 peaks at 1.5 x the mean rate.
    turn_s = 1.5 * abs(turn) / config.yaw_rate_max_rad_s

    def yaw(times: NDArray[np.float64]) -> NDArray[np.float64]:
        if turn_s == 0.0:
            return np.full(len(times), target.yaw_rad)
        x = _clip((times - t0_s) / turn_s, 0.0, 1.0)
        angles = start.yaw_rad + turn * (3.0 * x**2 - 2.0 * x**3)
        return np.pi - np.mod(np.pi - angles, 2.0 * np.pi)

    return ReferenceTrajectory(path, yaw, t0_s + max(duration, turn_s), params or QuadrotorParams())
