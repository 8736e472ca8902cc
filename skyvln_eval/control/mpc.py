"""The paper's NMPC and the linear-MPC baseline: one QP machinery, two prediction models.

:class:`NmpcController` predicts with the nonlinear model (one RK4 step per interval) and
solves the NLP by sequential quadratic programming in the real-time-iteration form: each
control step linearises the problem at the previous plan shifted by one step (the warm
start; a hover guess on the first step), solves one structured QP with HPIPM (Gauss-Newton
Hessian, which is the exact Hessian of the least-squares cost) and applies the first input.
``MpcConfig.sqp_iterations > 1`` iterates further towards the converged NLP solution.

:class:`LinearMpcController` is the same problem with the model linearised at hover
(``x+ = A x + B (u - u_hover)``), one QP per step; the input bounds and rate limits are the
same linear constraints, and the spheres become half-spaces tangent to them, linearised at
the previous plan (each is conservative: a half-space outside the sphere).

A failed or non-finite solve never raises: the controller applies the next input of the
previous plan (``fallback_shift``, for at most a horizon) or eases to hover
(``fallback_hover``), flags the step failed and counts it in ``failures``.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.control.base import Command, Controller, SolveStats
from skyvln_eval.control.mpc_config import MpcConfig
from skyvln_eval.control.stage_qp import NZ, QpSolution, StageQp
from skyvln_eval.errors import ConfigError
from skyvln_eval.sim.obstacles import ObstacleForecast
from skyvln_eval.sim.quadrotor import NU, NX, DroneState, rk4_symbolic
from skyvln_eval.sim.reference import ReferenceWindow

#: Slack above this (m^2 of squared keep-out radius) means an obstacle constraint was relaxed.
SLACK_TOLERANCE = 1e-6


class MpcController(Controller):
    """Shared receding-horizon logic; subclasses choose the prediction model."""

    def __init__(self, config: MpcConfig | None = None) -> None:
        self.config = config or MpcConfig()
        super().__init__(self.config.params, self.config.limits)
        self.horizon_steps = self.config.horizon_steps
        self.dt_s = self.config.dt_s
        self.qp = StageQp(self.prediction_model(), self.config, self.name)
        self._plan: NDArray[np.float64] | None = None  # last solution, relative to _plan_origin
        self._plan_origin = np.zeros(3)
        self._plan_age = 0  # control steps since the plan was computed

    @abstractmethod
    def prediction_model(self) -> ca.Function:
        """The discrete model ``x+ = F(x, u)`` the controller predicts with."""

    def reset(self) -> None:
        super().reset()
        self._plan = None
        self._plan_age = 0

    def settings(self) -> dict[str, Any]:
        return {**super().settings(), **self.config.as_dict(), "compiled": self.qp.compiled}

    def step(
        self, state: DroneState, reference: ReferenceWindow, obstacles: ObstacleForecast
    ) -> Command:
        start = time.perf_counter()
        n = self.horizon_steps
        if len(reference.times_s) < n + 1 or obstacles.positions_m.shape[1] < n + 1:
            raise ConfigError(
                f"{self.name} needs the reference and the obstacle forecast at {n + 1} times "
                f"(now and {n} steps of {self.dt_s} s), got {len(reference.times_s)} and "
                f"{obstacles.positions_m.shape[1]}"
            )
        yaw_ref = (
            float(reference.yaw_rad[0]) if np.isfinite(reference.yaw_rad[0]) else state.yaw_rad
        )
        inputs_ok = state.is_finite() and np.isfinite(reference.states[: n + 1]).all()
        inputs_ok = inputs_ok and np.isfinite(reference.inputs[:n]).all()
        inputs_ok = inputs_ok and np.isfinite(obstacles.positions_m).all()
        if not inputs_ok:
            return self._fallback(start, 0, "invalid_input", yaw_ref)
        origin = state.position_m
        x0 = state.model_vector()
        x0[:3] -= origin
        x_ref = reference.states[: n + 1].copy()
        x_ref[:, :3] -= origin
        params = self.qp.pack(
            x0,
            self.previous_input,
            x_ref,
            reference.inputs[:n],
            *self._obstacle_slots(obstacles, origin),
        )
        w_bar = self._initial_guess(x0, origin)
        solution, iterations = None, 0
        for _ in range(self.config.sqp_iterations):
            try:
                attempt = self.qp.solve(w_bar, params)
            except RuntimeError as error:  # CasADi reports solver crashes this way
                attempt = QpSolution(w_bar, False, 0, f"error: {error}")
            iterations += max(attempt.iterations, 0)
            if not attempt.success:
                break
            change = float(np.max(np.abs(attempt.w - w_bar)))
            solution = w_bar = attempt.w
            if change < self.config.sqp_step_tolerance:
                break
        if solution is None:
            return self._fallback(start, iterations, "", yaw_ref)
        self._plan, self._plan_origin, self._plan_age = solution, origin, 0
        u = self.clip_input(solution[NZ : NZ + NU])
        slack = float(np.max(solution[self.qp.slack_index], initial=0.0))
        status = "solved_soft" if slack > SLACK_TOLERANCE else "solved"
        elapsed_ms = (time.perf_counter() - start) * 1e3
        return self.command(u, yaw_ref, SolveStats(elapsed_ms, iterations, status))

    def _obstacle_slots(
        self, obstacles: ObstacleForecast, origin: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The nearest ``max_obstacles`` obstacles at steps 1..N (relative), radii, active flags."""
        n, m = self.horizon_steps, self.config.max_obstacles
        positions = np.zeros((m, n, 3))
        keep_out = np.zeros(m)
        active = np.zeros(m)
        if obstacles.count and m:
            future = obstacles.positions_m[:, 1 : n + 1, :] - origin
            margin = np.min(np.linalg.norm(future, axis=2), axis=1) - obstacles.keep_out_radius_m
            chosen = np.argsort(margin, kind="stable")[:m]
            positions[: len(chosen)] = future[chosen]
            keep_out[: len(chosen)] = (
                obstacles.keep_out_radius_m[chosen] + self.config.obstacle_margin_m
            )
            active[: len(chosen)] = 1.0
        return positions, keep_out, active

    def _initial_guess(
        self, x0: NDArray[np.float64], origin: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """The previous plan shifted to now (one step, more after fallbacks) and re-expressed
        in the new origin, else a hover guess."""
        stage, first = self.qp.stage, np.concatenate([x0, self.previous_input])
        if self._plan is None:
            guess = np.zeros((self.horizon_steps + 1, stage))
            guess[:, :NZ] = first
            guess[:, NZ : NZ + NU] = self.previous_input
            return guess.ravel()[: self.qp.n_w]
        plan = self._plan.copy()
        plan[self.qp.position_index] += np.tile(self._plan_origin - origin, self.horizon_steps + 1)
        shift = min(self._plan_age + 1, self.horizon_steps)
        # Drop the stages already flown; repeat the last input and state to fill the horizon.
        guess = np.concatenate([plan[shift * stage :], np.tile(plan[-stage:], shift)])
        guess[:NZ] = first
        return guess

    def _fallback(self, start: float, iterations: int, reason: str, yaw_ref: float) -> Command:
        """The next input of the previous plan while it lasts, else ease to hover."""
        stage = self.qp.stage
        self._plan_age += 1
        if self._plan is not None and self._plan_age < self.horizon_steps:
            u = self._plan[self._plan_age * stage + NZ : self._plan_age * stage + NZ + NU]
            status = "fallback_shift"
        else:
            u, status = self.safe_input(), "fallback_hover"
        if not np.isfinite(u).all():
            u, status = self.safe_input(), "fallback_hover"
        if reason:
            status = f"{status}:{reason}"
        elapsed_ms = (time.perf_counter() - start) * 1e3
        return self.command(
            self.clip_input(u), yaw_ref, SolveStats(elapsed_ms, iterations, status, failed=True)
        )


class NmpcController(MpcController):
    """The paper's NMPC: the nonlinear model, SQP real-time iterations with HPIPM."""

    name = "nmpc"

    def prediction_model(self) -> ca.Function:
        return rk4_symbolic(self.config.params, self.config.dt_s)


class LinearMpcController(MpcController):
    """Linear MPC: the model linearised at hover, one QP per control step."""

    name = "mpc"

    def prediction_model(self) -> ca.Function:
        nonlinear = rk4_symbolic(self.config.params, self.config.dt_s)
        x, u = ca.SX.sym("x", NX), ca.SX.sym("u", NU)
        hover_x, hover_u = ca.DM.zeros(NX), ca.DM(self.hover_input())
        a = ca.evalf(
            ca.substitute(
                ca.jacobian(nonlinear(x, u), x), ca.vertcat(x, u), ca.vertcat(hover_x, hover_u)
            )
        )
        b = ca.evalf(
            ca.substitute(
                ca.jacobian(nonlinear(x, u), u), ca.vertcat(x, u), ca.vertcat(hover_x, hover_u)
            )
        )
        return ca.Function(
            "quadrotor_hover_linear", [x, u], [ca.mtimes(a, x) + ca.mtimes(b, u - hover_u)]
        )
