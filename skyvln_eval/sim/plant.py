"""The simulated drone: the paper's model integrated with RK4, plus wind, sensor noise and yaw.

The plant integrates :func:`~skyvln_eval.sim.quadrotor.model_rhs` with several RK4 sub-steps
per control step (the controllers predict with one: at the default 0.1 s step the two
differ by micrometres, no real mismatch), holds each command constant over the step
(zero-order hold), saturates it to the actuator limits, and adds what the controllers'
model lacks: wind (a constant mean plus a seeded Ornstein-Uhlenbeck gust on the air
velocity that drag acts on) and the heading loop
``yaw' = clip(wrap(yaw_ref - yaw) / tau_yaw, +-yaw_rate_max)``. :meth:`Plant.measure`
returns the state with seeded Gaussian sensor noise. Wind and noise are off by default
(the nominal plant): the model mismatch of a closed loop is what they are set to.

The integration is one CasADi function per plant configuration (built once per process,
evaluated through a buffer: a few microseconds a step where Python floats took a quarter
of a millisecond), with the operations of :func:`rk4_step_floats`, which stays as the
plain-float reference: the two give the same states, bit for bit.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError
from skyvln_eval.frames import wrap_angle_rad
from skyvln_eval.native_calls import NATIVE_CALLS
from skyvln_eval.sim.quadrotor import (
    NX,
    DroneState,
    InputLimits,
    QuadrotorParams,
    model_rhs,
    require_non_negative,
    require_positive,
)


@dataclass(frozen=True)
class WindConfig:
    """Air velocity in ENU m/s: a constant mean plus a first-order (OU) random gust."""

    mean_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_m_s: float = 0.0
    gust_time_constant_s: float = 2.0

    def __post_init__(self) -> None:
        if len(self.mean_m_s) != 3 or not all(math.isfinite(v) for v in self.mean_m_s):
            raise ConfigError(
                f"WindConfig.mean_m_s must be 3 finite numbers, got {self.mean_m_s!r}"
            )
        require_non_negative(self, "gust_std_m_s")
        require_positive(self, "gust_time_constant_s")


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the Gaussian noise :meth:`Plant.measure` adds (0 = exact)."""

    position_std_m: float = 0.0
    velocity_std_m_s: float = 0.0
    attitude_std_rad: float = 0.0

    def __post_init__(self) -> None:
        require_non_negative(self, "position_std_m", "velocity_std_m_s", "attitude_std_rad")


@dataclass(frozen=True)
class PlantConfig:
    """Everything that defines the simulated drone; ``substeps`` RK4 steps per control step."""

    params: QuadrotorParams = field(default_factory=QuadrotorParams)
    limits: InputLimits = field(default_factory=InputLimits)
    wind: WindConfig = field(default_factory=WindConfig)
    noise: SensorNoise = field(default_factory=SensorNoise)
    substeps: int = 4

    def __post_init__(self) -> None:
        if not isinstance(self.substeps, int) or self.substeps < 1:
            raise ConfigError(
                f"PlantConfig.substeps must be an integer >= 1, got {self.substeps!r}"
            )


def _axpy(x: list[Any], a: Any, y: list[Any]) -> list[Any]:
    """``x + a * y`` element-wise (plain floats or CasADi symbols)."""
    return [xi + a * yi for xi, yi in zip(x, y, strict=True)]


def _wrap(angle: Any) -> Any:
    """:func:`~skyvln_eval.frames.wrap_angle_rad` for CasADi symbols: Python's float ``%``
    is C's ``fmod`` moved into ``[0, 2 pi)``, which this does with the same operations."""
    import casadi as ca

    rest = ca.fmod(math.pi - angle, 2.0 * math.pi)
    return math.pi - ca.if_else(rest < 0, rest + 2.0 * math.pi, rest)


def _rhs(
    x: list[Any], u: Any, wind: list[Any], yaw_ref: Any, params: QuadrotorParams, symbolic: bool
) -> list[Any]:
    """The model's derivative plus the heading loop's (floats, or CasADi symbols)."""
    derivative = model_rhs(x, u, params, wind)
    wrap = _wrap if symbolic else wrap_angle_rad
    yaw_rate = wrap(yaw_ref - x[NX]) / params.yaw_time_constant_s
    if symbolic:
        import casadi as ca

        yaw_rate = ca.fmin(ca.fmax(yaw_rate, -params.yaw_rate_max_rad_s), params.yaw_rate_max_rad_s)
    else:
        yaw_rate = min(max(yaw_rate, -params.yaw_rate_max_rad_s), params.yaw_rate_max_rad_s)
    return [*derivative, yaw_rate]


def rk4_step_floats(
    x: list[float],
    u: tuple[float, float, float],
    wind: list[float],
    yaw_ref: float,
    h: float,
    substeps: int,
    params: QuadrotorParams,
) -> list[float]:
    """``substeps`` RK4 steps of ``h`` seconds of the plant, on plain floats (the reference
    for the compiled step; ``x`` is the model state plus yaw)."""
    return _rk4(x, u, wind, yaw_ref, h, substeps, params, symbolic=False)


def _rk4(
    x: list[Any],
    u: Any,
    wind: list[Any],
    yaw_ref: Any,
    h: Any,
    substeps: int,
    params: QuadrotorParams,
    symbolic: bool,
) -> list[Any]:
    for _ in range(substeps):
        k1 = _rhs(x, u, wind, yaw_ref, params, symbolic)
        k2 = _rhs(_axpy(x, h / 2, k1), u, wind, yaw_ref, params, symbolic)
        k3 = _rhs(_axpy(x, h / 2, k2), u, wind, yaw_ref, params, symbolic)
        k4 = _rhs(_axpy(x, h, k3), u, wind, yaw_ref, params, symbolic)
        slope = [b1 + 2 * b2 + 2 * b3 + b4 for b1, b2, b3, b4 in zip(k1, k2, k3, k4, strict=True)]
        x = _axpy(x, h / 6, slope)
    wrapped = (_wrap if symbolic else wrap_angle_rad)(x[NX])
    return [*x[:NX], wrapped]


@functools.lru_cache(maxsize=8)
def _step_function(params: QuadrotorParams, substeps: int) -> Any:
    """``(x, u, wind, yaw_ref, h) -> x+``: one control step of the plant as a CasADi Function,
    built once per process (call it under :data:`NATIVE_CALLS`: CasADi's symbolic core is
    not thread-safe, and threads that all miss the cache would each build it)."""
    import casadi as ca

    x, u, wind = ca.SX.sym("x", NX + 1), ca.SX.sym("u", 3), ca.SX.sym("wind", 3)
    yaw_ref, h = ca.SX.sym("yaw_ref"), ca.SX.sym("h")
    x_next = _rk4(
        ca.vertsplit(x), ca.vertsplit(u), ca.vertsplit(wind), yaw_ref, h, substeps, params, True
    )
    return ca.Function("plant_step", [x, u, wind, yaw_ref, h], [ca.vertcat(*x_next)])


class _StepBuffers:
    """Preallocated arrays bound to one evaluation buffer of the plant's step Function."""

    def __init__(self, params: QuadrotorParams, substeps: int) -> None:
        self.x, self.u, self.wind = np.zeros(NX + 1), np.zeros(3), np.zeros(3)
        self.yaw_ref, self.h, self.out = np.zeros(1), np.zeros(1), np.zeros(NX + 1)
        self._buffer: Any
        with NATIVE_CALLS:
            self._buffer, self._trigger = _step_function(params, substeps).buffer()
        for index, array in enumerate((self.x, self.u, self.wind, self.yaw_ref, self.h)):
            self._buffer.set_arg(index, array.data)
        self._buffer.set_res(0, self.out.data)

    def step(self) -> None:
        self._trigger()


class Plant:
    """The true drone. ``step`` advances it by one control step; ``measure`` reads its sensors."""

    def __init__(self, state: DroneState, config: PlantConfig | None = None, seed: int = 0) -> None:
        self.config = config or PlantConfig()
        self._buffers = _StepBuffers(self.config.params, self.config.substeps)
        # The true state (model state plus yaw) lives in the step Function's input buffer,
        # which each step overwrites with its result: no per-step copy or allocation.
        self._x = self._buffers.x
        self._x[:] = (*state.model_values(), state.yaw_rad)
        self._state: DroneState | None = None  # the true state of _x, made when first asked
        self._gust_m_s = np.zeros(3)
        self._wind_mean_m_s = np.asarray(self.config.wind.mean_m_s, dtype=np.float64)
        noise = self.config.noise  # frozen: its spreads are the same every step
        self._noise_std = np.array(
            [noise.position_std_m] * 3 + [noise.velocity_std_m_s] * 3 + [noise.attitude_std_rad] * 3
        )
        self._noisy = bool(self._noise_std.any())
        # Two streams, so turning noise on or off does not change the wind a run sees.
        self._wind_rng = np.random.default_rng([seed, 0])
        self._noise_rng = np.random.default_rng([seed, 1])

    @property
    def state(self) -> DroneState:
        """The true state (no noise); made once per step (the flight loop asks several times)."""
        if self._state is None:
            self._state = DroneState.from_model_vector(self._x[:NX], self._x[NX])
        return self._state

    @property
    def wind_m_s(self) -> NDArray[np.float64]:
        return self._wind_mean_m_s + self._gust_m_s

    def step(
        self,
        thrust_m_s2: float,
        roll_ref_rad: float,
        pitch_ref_rad: float,
        yaw_ref_rad: float,
        dt_s: float,
    ) -> DroneState:
        """Apply one command for ``dt_s`` seconds (saturated to the limits); the new true state."""
        limits = self.config.limits
        u = (
            min(max(thrust_m_s2, limits.thrust_min_m_s2), limits.thrust_max_m_s2),
            min(max(roll_ref_rad, -limits.tilt_ref_max_rad), limits.tilt_ref_max_rad),
            min(max(pitch_ref_rad, -limits.tilt_ref_max_rad), limits.tilt_ref_max_rad),
        )
        buffers = self._buffers  # buffers.x is self._x, the state now
        buffers.u[:] = u
        np.add(self._wind_mean_m_s, self._gust_m_s, out=buffers.wind)  # wind_m_s, in place
        buffers.yaw_ref[0] = yaw_ref_rad
        buffers.h[0] = dt_s / self.config.substeps
        buffers.step()
        self._x[:] = buffers.out
        self._state = None
        self._advance_gust(dt_s)
        return self.state

    def measure(self) -> DroneState:
        """The state as the sensors report it (true state plus seeded Gaussian noise)."""
        if not self._noisy:
            return self.state
        x = self._x + self._noise_std * self._noise_rng.standard_normal(NX + 1)
        return DroneState.from_model_vector(x[:NX], wrap_angle_rad(float(x[NX])))

    def _advance_gust(self, dt_s: float) -> None:
        wind = self.config.wind
        if wind.gust_std_m_s == 0.0:
            return
        # Exact discretisation of an OU process with stationary std gust_std_m_s.
        decay = math.exp(-dt_s / wind.gust_time_constant_s)
        spread = wind.gust_std_m_s * math.sqrt(1.0 - decay**2)
        self._gust_m_s = decay * self._gust_m_s + spread * self._wind_rng.standard_normal(3)
