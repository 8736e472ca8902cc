"""Cascaded PID, the kind of controller AirSim's simple flight uses: position -> velocity ->
attitude.

The outer loop turns the position error into a velocity set-point (P, plus the reference
velocity as feed-forward, capped at ``max_speed_m_s``); the inner loop turns the velocity
error into an acceleration set-point (PID with a clamped integral against wind and drag);
the acceleration becomes thrust and world-frame roll / pitch by inverting the thrust
direction of the model, and the roll / pitch references divide out the attitude loop's DC
gain K. The command is then held within the same input bounds and per-step rate limits as
the MPCs. It knows nothing of obstacles: it flies straight through them, which is what the
paper's ablation compares against.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from skyvln_eval.control.base import Command, Controller, SolveStats
from skyvln_eval.errors import ConfigError
from skyvln_eval.sim.obstacles import ObstacleForecast
from skyvln_eval.sim.quadrotor import (
    DroneState,
    InputLimits,
    QuadrotorParams,
    require_non_negative,
    require_positive,
)
from skyvln_eval.sim.reference import ReferenceWindow


@dataclass(frozen=True)
class PidConfig:
    """Gains of the cascade (per axis, the same for x, y and z)."""

    dt_s: float = 0.1
    #: Outer loop: velocity set-point per metre of position error (1/s).
    position_gain_1_s: float = 1.0
    #: Inner loop on the velocity error: P (1/s), I (1/s^2), D (-).
    velocity_gain_1_s: float = 2.0
    velocity_integral_gain_1_s2: float = 0.4
    velocity_derivative_gain: float = 0.05
    #: Bound on each axis of the integral term's acceleration (m/s^2), against wind-up.
    integral_limit_m_s2: float = 2.0
    max_speed_m_s: float = 5.0
    velocity_feedforward: bool = True
    limits: InputLimits = field(default_factory=InputLimits)
    params: QuadrotorParams = field(default_factory=QuadrotorParams)

    def __post_init__(self) -> None:
        require_positive(self, "dt_s", "position_gain_1_s", "velocity_gain_1_s", "max_speed_m_s")
        require_non_negative(
            self, "velocity_integral_gain_1_s2", "velocity_derivative_gain", "integral_limit_m_s2"
        )
        if not isinstance(self.velocity_feedforward, bool):
            raise ConfigError(
                "PidConfig.velocity_feedforward must be true or false, got "
                f"{self.velocity_feedforward!r}"
            )


class PidController(Controller):
    """Cascaded PID: position -> velocity -> thrust, roll_ref, pitch_ref."""

    name = "pid"
    horizon_steps = 0

    def __init__(self, config: PidConfig | None = None) -> None:
        self.config = config or PidConfig()
        super().__init__(self.config.params, self.config.limits)
        self.dt_s = self.config.dt_s
        self._integral = np.zeros(3)
        self._last_velocity_error: np.ndarray | None = None

    def reset(self) -> None:
        super().reset()
        self._integral = np.zeros(3)
        self._last_velocity_error = None

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), **asdict(self.config)}

    def step(
        self, state: DroneState, reference: ReferenceWindow, obstacles: ObstacleForecast
    ) -> Command:
        start = time.perf_counter()
        cfg, p = self.config, self.params
        yaw_ref = float(reference.yaw_rad[0])
        if not (state.is_finite() and np.isfinite(reference.states[0]).all()):
            self._last_velocity_error = None
            u = self.clip_input(self.safe_input())
            stats = SolveStats(
                (time.perf_counter() - start) * 1e3, 0, "fallback_hover:invalid_input", True
            )
            return self.command(u, yaw_ref if math.isfinite(yaw_ref) else 0.0, stats)
        velocity_sp = cfg.position_gain_1_s * (reference.position_m[0] - state.position_m)
        if cfg.velocity_feedforward:
            velocity_sp = velocity_sp + reference.velocity_m_s[0]
        speed = float(np.linalg.norm(velocity_sp))
        if speed > cfg.max_speed_m_s:
            velocity_sp *= cfg.max_speed_m_s / speed
        error = velocity_sp - state.velocity_m_s
        self._integral = np.clip(
            self._integral + cfg.velocity_integral_gain_1_s2 * error * self.dt_s,
            -cfg.integral_limit_m_s2,
            cfg.integral_limit_m_s2,
        )
        derivative = np.zeros(3)
        if self._last_velocity_error is not None:
            derivative = (error - self._last_velocity_error) / self.dt_s
        self._last_velocity_error = error
        acceleration = (
            cfg.velocity_gain_1_s * error
            + self._integral
            + cfg.velocity_derivative_gain * derivative
        )
        # Thrust vector f = a + g e3; the model's R(roll, pitch) [0, 0, T] = f gives the attitude.
        force = acceleration + np.array([0.0, 0.0, p.gravity_m_s2])
        force[2] = max(force[2], 0.1 * p.gravity_m_s2)  # never ask to fly upside down
        thrust = float(np.linalg.norm(force))
        roll = math.asin(max(-1.0, min(1.0, -force[1] / thrust)))
        pitch = math.atan2(force[0], force[2])
        _, roll_ref, pitch_ref = self.clipped_values(
            thrust, roll / p.roll_gain, pitch / p.pitch_gain
        )
        # The vertical loop keeps priority: the thrust whose vertical part is the one asked
        # for at the tilt the bounds and rate limits leave (the force's norm, when they
        # leave its tilt). With the tilt cut, the norm put the horizontal excess into the
        # climb (an audit: 19 km of altitude under 5 m/s velocity noise).
        vertical = math.cos(roll_ref * p.roll_gain) * math.cos(pitch_ref * p.pitch_gain)
        u = self.clip_input(np.array([force[2] / vertical, roll_ref, pitch_ref]))
        stats = SolveStats((time.perf_counter() - start) * 1e3, 0, "solved")
        return self.command(u, yaw_ref, stats)
