"""Settings of the MPC controllers (NMPC and linear MPC), with documented defaults.

The weights are those the project's NMPC notes measured:
``Qx = diag(10, 10, 10, 1, 1, 1, .5, .5)``,
``Qu = diag(.5, 5, 5)``, ``Q_du = diag(.5, 20, 20)`` around ``u_ref`` (hover thrust plus the
reference's feed-forward), N = 20 steps of dt = 0.1 s.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from skyvln_eval.errors import ConfigError
from skyvln_eval.sim.quadrotor import (
    NU,
    NX,
    InputLimits,
    QuadrotorParams,
    require_non_negative,
    require_positive,
)

#: ``"auto"`` compiles the solver's functions to C when a compiler is found (cached), else
#: runs them interpreted with one warning; ``"always"`` fails without a compiler; ``"never"``
#: always interprets.
CompileMode = Literal["auto", "always", "never"]
#: ``"riccati"``: the compiled interior point method with a Riccati recursion
#: (:mod:`skyvln_eval.control.stage_ipm`; needs a C compiler, else HPIPM with a warning);
#: ``"hpipm"``: HPIPM through CasADi (compiled or interpreted as ``compile`` says).
QpSolver = Literal["riccati", "hpipm"]


@dataclass(frozen=True)
class MpcWeights:
    """Diagonal weights of the paper's cost and of the obstacle slack."""

    #: Q_x on ``[x, y, z, vx, vy, vz, roll, pitch]`` errors.
    state: tuple[float, ...] = (10.0, 10.0, 10.0, 1.0, 1.0, 1.0, 0.5, 0.5)
    #: Q_u on ``[T, roll_ref, pitch_ref]`` errors from ``u_ref``.
    input: tuple[float, ...] = (0.5, 5.0, 5.0)
    #: Q_du on the change of ``[T, roll_ref, pitch_ref]`` from the previous step.
    input_rate: tuple[float, ...] = (0.5, 20.0, 20.0)
    #: Multiplies Q_x at the last horizon step.
    terminal_scale: float = 1.0
    #: The obstacle constraints are soft only as a last resort: an exact L1 penalty (per m^2
    #: of squared keep-out radius violated) far above any tracking gain keeps them hard
    #: whenever they can be met, and a start inside an obstacle still gets the way out.
    slack_linear: float = 1.0e4
    slack_quadratic: float = 1.0e2

    def __post_init__(self) -> None:
        for name, size in (("state", NX), ("input", NU), ("input_rate", NU)):
            values = getattr(self, name)
            if len(values) != size or not all(math.isfinite(v) and v >= 0 for v in values):
                raise ConfigError(
                    f"MpcWeights.{name} must be {size} finite numbers >= 0, got {values!r}"
                )
        require_positive(self, "terminal_scale", "slack_linear", "slack_quadratic")


#: Where classical RK4's stability region meets the negative real axis (|R(z)| = 1 at
#: z = -2.785...): the largest step, in time constants, that a decaying mode survives.
RK4_REAL_STABILITY = 2.785


@dataclass(frozen=True)
class MpcConfig:
    """One MPC controller's settings (shared by the NMPC and the linear MPC)."""

    horizon_steps: int = 20
    dt_s: float = 0.1
    #: Obstacle slots in the problem; the nearest obstacles of the forecast fill them.
    max_obstacles: int = 2
    #: Added to r_obs + r_s inside the controller: the constraint holds at the predicted
    #: samples of a one-step RK4 model, while the plant is integrated finer and may carry
    #: wind and noise, so a few centimetres keep the true clearance at or above zero. The
    #: controller widens it further by the step length (``_sampled_radii``: the path between
    #: samples keeps out too), as the flight log measures clearance over whole steps.
    obstacle_margin_m: float = 0.05
    weights: MpcWeights = field(default_factory=MpcWeights)
    limits: InputLimits = field(default_factory=InputLimits)
    params: QuadrotorParams = field(default_factory=QuadrotorParams)
    #: SQP iterations per control step: 1 is the real-time iteration (RTI); more iterate
    #: towards the converged NLP solution (stopping early once the step is below tolerance).
    sqp_iterations: int = 1
    sqp_step_tolerance: float = 1e-4
    compile: CompileMode = "auto"
    qp_solver: QpSolver = "riccati"

    def __post_init__(self) -> None:
        for name in ("horizon_steps", "max_obstacles", "sqp_iterations"):
            value = getattr(self, name)
            minimum = 0 if name == "max_obstacles" else 1
            if not isinstance(value, int) or value < minimum:
                raise ConfigError(
                    f"MpcConfig.{name} must be an integer >= {minimum}, got {value!r}"
                )
        require_positive(self, "dt_s", "sqp_step_tolerance")
        require_non_negative(self, "obstacle_margin_m")
        # The prediction model takes one RK4 step per interval: for a first-order loop of
        # time constant tau, RK4 is stable only while dt / tau <= 2.785 (its stability
        # interval on the negative real axis); beyond, the predicted attitude diverges and
        # the controller flies a model that is not the drone's (an audit's dt 1 s: 53 m off).
        tau = min(self.params.roll_time_constant_s, self.params.pitch_time_constant_s)
        if self.dt_s > RK4_REAL_STABILITY * tau:
            raise ConfigError(
                f"MpcConfig.dt_s must be at most {RK4_REAL_STABILITY * tau:.3f} s, got "
                f"{self.dt_s!r}: the model's one RK4 step per interval is unstable for the "
                f"attitude loop (time constant {tau} s) beyond it"
            )
        if self.qp_solver not in ("riccati", "hpipm"):
            raise ConfigError(
                f"MpcConfig.qp_solver must be 'riccati' or 'hpipm', got {self.qp_solver!r}"
            )
        if self.compile not in ("auto", "always", "never"):
            raise ConfigError(
                f"MpcConfig.compile must be 'auto', 'always' or 'never', got {self.compile!r}"
            )

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)
