"""The paper's quadrotor model (Eq. "kinetics"), its parameters, input limits and state.

State ``x = [p, v, roll, pitch]`` (ENU metres, m/s, rad), inputs
``u = [T, roll_ref, pitch_ref]`` (mass-normalised thrust in m/s^2, rad, rad):

    p'     = v
    v'     = R(roll, pitch) [0, 0, T] + [0, 0, -g] - diag(Ax, Ay, Az) v
    roll'  = (K_roll  roll_ref  - roll)  / tau_roll
    pitch' = (K_pitch pitch_ref - pitch) / tau_pitch

``R = Rz(0) Ry(pitch) Rx(roll)``: roll and pitch are world-frame angles about x (east) and
y (north), so a positive pitch accelerates east and a positive roll accelerates south. The
model has no yaw; the plant holds yaw with a separate first-order heading loop
(:class:`QuadrotorParams.yaw_time_constant_s`), and the attitude controller is assumed to
track world-frame roll / pitch references whatever the heading ("after the relevant mapping"
in the paper), so yaw never enters the translational dynamics.

Default values are those of an AscTec Firefly identified in ETH's mav_control_rw (the
values measured in the project's NMPC notes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import ConfigError

#: Names of the model state, in the order of the state vector.
STATE_NAMES = ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "roll_rad", "pitch_rad")
#: Names of the model inputs, in the order of the input vector.
INPUT_NAMES = ("thrust_m_s2", "roll_ref_rad", "pitch_ref_rad")
NX = len(STATE_NAMES)
NU = len(INPUT_NAMES)


def require_positive(owner: object, *names: str) -> None:
    """Raise a :class:`ConfigError` naming the first field of ``owner`` that is not > 0."""
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ConfigError(
                f"{type(owner).__name__}.{name} must be a positive number, got {value!r}"
            )


def require_non_negative(owner: object, *names: str) -> None:
    """Raise a :class:`ConfigError` naming the first field of ``owner`` that is not >= 0."""
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise ConfigError(f"{type(owner).__name__}.{name} must be a number >= 0, got {value!r}")


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of the model (defaults: AscTec Firefly, mav_control_rw)."""

    gravity_m_s2: float = 9.81
    #: Linear drag ``A = diag(Ax, Ay, Az)`` in 1/s (acceleration per unit velocity).
    drag_x_1_s: float = 0.1
    drag_y_1_s: float = 0.1
    drag_z_1_s: float = 0.2
    #: First-order closed-loop attitude: gain K (-) and time constant tau (s).
    roll_gain: float = 0.75
    roll_time_constant_s: float = 0.257
    pitch_gain: float = 0.78
    pitch_time_constant_s: float = 0.259
    #: The separate heading loop of the plant (not part of the model): first order, rate-limited.
    yaw_time_constant_s: float = 0.5
    yaw_rate_max_rad_s: float = 1.0

    def __post_init__(self) -> None:
        require_positive(
            self,
            "gravity_m_s2",
            "roll_gain",
            "roll_time_constant_s",
            "pitch_gain",
            "pitch_time_constant_s",
            "yaw_time_constant_s",
            "yaw_rate_max_rad_s",
        )
        require_non_negative(self, "drag_x_1_s", "drag_y_1_s", "drag_z_1_s")


@dataclass(frozen=True)
class InputLimits:
    """Actuator limits every controller respects and the plant saturates to."""

    thrust_min_m_s2: float = 5.0
    thrust_max_m_s2: float = 20.0
    #: Bound on |roll_ref| and |pitch_ref| (25 degrees).
    tilt_ref_max_rad: float = math.radians(25.0)
    #: Bound on the change of roll_ref and pitch_ref per control step, the applied input included.
    tilt_ref_step_max_rad: float = 0.1

    def __post_init__(self) -> None:
        require_non_negative(self, "thrust_min_m_s2")
        require_positive(self, "thrust_max_m_s2", "tilt_ref_max_rad", "tilt_ref_step_max_rad")
        if self.thrust_max_m_s2 <= self.thrust_min_m_s2:
            raise ConfigError(
                "InputLimits.thrust_max_m_s2 must exceed thrust_min_m_s2, got "
                f"{self.thrust_max_m_s2!r} <= {self.thrust_min_m_s2!r}"
            )
        if self.tilt_ref_max_rad >= math.pi / 2:
            raise ConfigError(
                f"InputLimits.tilt_ref_max_rad must be below pi/2, got {self.tilt_ref_max_rad!r}"
            )


@dataclass(frozen=True)
class DroneState:
    """Full drone state in the ENU frame: the model state plus the heading (yaw)."""

    x_m: float
    y_m: float
    z_m: float
    vx_m_s: float = 0.0
    vy_m_s: float = 0.0
    vz_m_s: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    @classmethod
    def from_model_vector(
        cls, x: Sequence[float] | NDArray[np.float64], yaw_rad: float
    ) -> DroneState:
        """From the 8-vector ``[p, v, roll, pitch]`` and a yaw."""
        # One conversion to Python floats (the plant makes a state every control step); a
        # vector of another length fails to unpack.
        x_m, y_m, z_m, vx, vy, vz, roll, pitch = np.asarray(x[:NX], dtype=np.float64).tolist()
        return cls(x_m, y_m, z_m, vx, vy, vz, roll, pitch, float(yaw_rad))

    def model_vector(self) -> NDArray[np.float64]:
        """The model state ``[p, v, roll, pitch]`` as an 8-vector."""
        return np.array(self.model_values(), dtype=np.float64)

    def model_values(self) -> tuple[float, ...]:
        """The model state ``[p, v, roll, pitch]`` as plain floats (in STATE_NAMES order)."""
        return (
            self.x_m,
            self.y_m,
            self.z_m,
            self.vx_m_s,
            self.vy_m_s,
            self.vz_m_s,
            self.roll_rad,
            self.pitch_rad,
        )

    @property
    def position_m(self) -> NDArray[np.float64]:
        return np.array([self.x_m, self.y_m, self.z_m])

    @property
    def velocity_m_s(self) -> NDArray[np.float64]:
        return np.array([self.vx_m_s, self.vy_m_s, self.vz_m_s])

    def is_finite(self) -> bool:
        return all(map(math.isfinite, self.model_values())) and math.isfinite(self.yaw_rad)


def hover_input(params: QuadrotorParams) -> NDArray[np.float64]:
    """The input that holds a hover: ``[g, 0, 0]``."""
    return np.array([params.gravity_m_s2, 0.0, 0.0])


def model_rhs(
    x: Any, u: Any, params: QuadrotorParams, wind_m_s: Sequence[Any] = (0.0, 0.0, 0.0)
) -> list[Any]:
    """Time derivative of ``x`` under input ``u``, element-wise.

    Written once for floats (the plant) and CasADi symbols (the controllers' model). Drag
    acts on the velocity relative to the air, ``v - wind``; the controllers' model has none.
    """
    ops: Any = math if isinstance(x[6], float | int) else _casadi()
    vx, vy, vz, roll, pitch = x[3], x[4], x[5], x[6], x[7]
    thrust, roll_ref, pitch_ref = u[0], u[1], u[2]
    g = params.gravity_m_s2
    # R(roll, pitch) [0, 0, T] with R = Ry(pitch) Rx(roll): the thrust direction in ENU.
    ax = thrust * ops.cos(roll) * ops.sin(pitch) - params.drag_x_1_s * (vx - wind_m_s[0])
    ay = -thrust * ops.sin(roll) - params.drag_y_1_s * (vy - wind_m_s[1])
    az = thrust * ops.cos(roll) * ops.cos(pitch) - g - params.drag_z_1_s * (vz - wind_m_s[2])
    roll_dot = (params.roll_gain * roll_ref - roll) / params.roll_time_constant_s
    pitch_dot = (params.pitch_gain * pitch_ref - pitch) / params.pitch_time_constant_s
    return [vx, vy, vz, ax, ay, az, roll_dot, pitch_dot]


def _casadi() -> Any:
    import casadi  # only the controllers need symbols; the plant runs on floats

    return casadi


def rk4_symbolic(params: QuadrotorParams, dt_s: float, steps: int = 1) -> Any:
    """The discrete model ``x+ = F(x, u)``: ``steps`` RK4 steps over ``dt_s`` (a CasADi
    Function of SX ``x`` and ``u``)."""
    ca = _casadi()
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)

    def f(state: Any) -> Any:
        return ca.vertcat(*model_rhs(state, u, params))

    h = dt_s / steps
    state = x
    for _ in range(steps):
        k1 = f(state)
        k2 = f(state + h / 2 * k1)
        k3 = f(state + h / 2 * k2)
        k4 = f(state + h * k3)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("quadrotor_rk4", [x, u], [state], ["x", "u"], ["x_next"])


def attitude_for_acceleration(
    acceleration_m_s2: NDArray[np.float64],
    velocity_m_s: NDArray[np.float64],
    params: QuadrotorParams,
) -> tuple[float, float, float]:
    """Thrust, roll and pitch (steady state) that produce ``acceleration`` at ``velocity``.

    Inverts ``v' = R [0, 0, T] - g e3 - A v`` for the thrust vector ``f = v' + g e3 + A v``:
    ``T = |f|``, ``roll = asin(-f_y / T)``, ``pitch = atan2(f_x, f_z)``.
    """
    drag = np.array([params.drag_x_1_s, params.drag_y_1_s, params.drag_z_1_s])
    f = (
        np.asarray(acceleration_m_s2)
        + np.array([0.0, 0.0, params.gravity_m_s2])
        + drag * velocity_m_s
    )
    thrust = float(np.linalg.norm(f))
    roll = math.asin(max(-1.0, min(1.0, -f[1] / thrust)))
    pitch = math.atan2(f[0], f[2])
    return thrust, roll, pitch
