"""The one interface every controller implements, and what a step returns.

A controller speaks one verb: ``step(state, reference, obstacles) -> Command``. It is given
the measured state, the reference over its horizon (``horizon_steps + 1`` points spaced
``dt_s`` apart, the first one now) and the obstacle forecast at the same times; it returns
the inputs of the paper's model (thrust, roll and pitch references), the heading reference
for the plant's yaw loop, and how its solve went. A step never raises for a failed or
non-finite solve: it falls back to a safe command and says so in :class:`SolveStats`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.sim.obstacles import ObstacleForecast
from skyvln_eval.sim.quadrotor import DroneState, InputLimits, QuadrotorParams
from skyvln_eval.sim.reference import ReferenceWindow


@dataclass(frozen=True)
class SolveStats:
    """How one controller step went.

    ``status`` is ``"solved"`` on success, ``"solved_soft"`` when the obstacle constraints
    could only be met with slack (e.g. starting inside an obstacle), and on failure
    ``"fallback_shift"`` (the previous plan, shifted) or ``"fallback_hover"``; ``failed``
    is true exactly for the fallbacks.
    """

    solve_time_ms: float
    iterations: int
    status: str
    failed: bool = False


@dataclass(frozen=True)
class Command:
    """Inputs of the model (``[T, roll_ref, pitch_ref]``) plus the heading reference.

    ``predicted_positions_m`` is the path a predictive controller expects to fly, ``(N + 1,
    3)`` ENU metres from now to the end of its horizon, for the logs and the viewer;
    ``None`` for controllers without a prediction and for fallback commands.
    """

    thrust_m_s2: float
    roll_ref_rad: float
    pitch_ref_rad: float
    yaw_ref_rad: float
    stats: SolveStats
    predicted_positions_m: NDArray[np.float64] | None = field(
        default=None, repr=False, compare=False
    )

    @property
    def inputs(self) -> NDArray[np.float64]:
        return np.array([self.thrust_m_s2, self.roll_ref_rad, self.pitch_ref_rad])

    def is_finite(self) -> bool:
        values = (self.thrust_m_s2, self.roll_ref_rad, self.pitch_ref_rad, self.yaw_ref_rad)
        return all(math.isfinite(v) for v in values)


class Controller(ABC):
    """A tracking controller for the paper's quadrotor model.

    Subclasses set ``name``, ``horizon_steps`` (how many reference intervals ``step`` needs
    after now; 0 for a controller that only looks at the present) and ``dt_s``.
    ``failures`` counts the failed (fallback) steps since the controller was made;
    ``previous_input`` is the last input applied, which the rate limits start from.
    """

    name: str = "controller"
    horizon_steps: int = 0
    dt_s: float = 0.1

    def __init__(self, params: QuadrotorParams, limits: InputLimits) -> None:
        self.params = params
        self.limits = limits
        self.failures = 0
        self.previous_input = self.hover_input()

    @abstractmethod
    def step(
        self, state: DroneState, reference: ReferenceWindow, obstacles: ObstacleForecast
    ) -> Command:
        """One control step: the command to hold for the next ``dt_s`` seconds."""

    def reset(self) -> None:
        """Forget the warm start and the last input (a new flight from hover)."""
        self.previous_input = self.hover_input()

    def settings(self) -> dict[str, Any]:
        """The settings that define this controller, for the run log."""
        return {"name": self.name, "horizon_steps": self.horizon_steps, "dt_s": self.dt_s}

    def hover_input(self) -> NDArray[np.float64]:
        return np.array([self.params.gravity_m_s2, 0.0, 0.0])

    def safe_input(self) -> NDArray[np.float64]:
        """Hover, reached from the last input within the per-step tilt-rate limit."""
        step = self.limits.tilt_ref_step_max_rad
        tilt = np.clip(-self.previous_input[1:], -step, step) + self.previous_input[1:]
        return np.array([self.params.gravity_m_s2, *tilt])

    def clip_input(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """``u`` within the input bounds and within one rate step of the previous input."""
        return np.array(self.clipped_values(float(u[0]), float(u[1]), float(u[2])))

    def clipped_values(
        self, thrust: float, roll_ref: float, pitch_ref: float
    ) -> tuple[float, float, float]:
        """:meth:`clip_input` on plain floats: three numbers do not need numpy's per-call
        overhead (the same comparisons, so the same values, NaN included)."""
        limits = self.limits
        step, tilt_max = limits.tilt_ref_step_max_rad, limits.tilt_ref_max_rad
        roll_before, pitch_before = float(self.previous_input[1]), float(self.previous_input[2])
        roll = min(max(roll_ref, roll_before - step), roll_before + step)
        pitch = min(max(pitch_ref, pitch_before - step), pitch_before + step)
        return (
            min(max(thrust, limits.thrust_min_m_s2), limits.thrust_max_m_s2),
            min(max(roll, -tilt_max), tilt_max),
            min(max(pitch, -tilt_max), tilt_max),
        )

    def command(
        self,
        u: NDArray[np.float64] | Sequence[float],
        yaw_ref_rad: float,
        stats: SolveStats,
        predicted_positions_m: NDArray[np.float64] | None = None,
    ) -> Command:
        """Record ``u`` as the applied input (for the rate limits) and wrap it as a Command."""
        self.previous_input = np.array(u, dtype=np.float64)  # a copy: the caller keeps u
        if stats.failed:
            self.failures += 1
        return Command(
            float(u[0]), float(u[1]), float(u[2]), float(yaw_ref_rad), stats, predicted_positions_m
        )
