"""The paper's NMPC and the linear-MPC baseline: one QP machinery, two prediction models.

:class:`NmpcController` predicts with the nonlinear model (one RK4 step per interval) and
solves the NLP by sequential quadratic programming in the real-time-iteration form: each
control step linearises the problem at the previous plan shifted by one step (the warm
start; a hover guess on the first step), solves one structured QP (Gauss-Newton Hessian,
which is the exact Hessian of the least-squares cost) and applies the first input.
Shift and linearisation are one compiled CasADi call per step and the QP is solved by the
compiled Riccati interior point method (:class:`~skyvln_eval.control.rti.RiccatiStep`;
``qp_solver: hpipm`` solves it with HPIPM inside the CasADi call instead); Python only
copies the measurements into preallocated buffers. ``MpcConfig.sqp_iterations > 1``
iterates further towards the converged NLP solution.

:class:`LinearMpcController` is the same problem with the model linearised at hover
(``x+ = A x + B (u - u_hover)``), one QP per step; the input bounds and rate limits are the
same linear constraints, and the spheres become half-spaces tangent to them, linearised at
the previous plan (each is conservative: a half-space outside the sphere).

A failed or non-finite solve never raises: the controller applies the next input of the
previous plan (``fallback_shift``, for at most a horizon) or eases to hover
(``fallback_hover``), flags the step failed and counts it in ``failures``.
"""

from __future__ import annotations

import json
import math
import threading
import time
import warnings
from abc import abstractmethod
from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.control.base import Command, Controller, SolveStats
from skyvln_eval.control.mpc_config import MpcConfig
from skyvln_eval.control.rti import (
    HpipmStep,
    RiccatiStep,
    StepBuffers,
    build_hpipm_step,
    build_riccati_step,
)
from skyvln_eval.control.stage_qp import NZ, StageQp
from skyvln_eval.errors import ConfigError, SolverBuildError
from skyvln_eval.native_calls import NATIVE_CALLS
from skyvln_eval.sim.obstacles import ObstacleForecast, row_norms
from skyvln_eval.sim.quadrotor import NU, NX, DroneState, rk4_symbolic
from skyvln_eval.sim.reference import ReferenceWindow

#: Slack above this (m^2 of squared keep-out radius) means an obstacle constraint was relaxed.
SLACK_TOLERANCE = 1e-6

_PROBLEMS: dict[str, tuple[StageQp, Callable[[], StepBuffers], str]] = {}
_PROBLEMS_LOCK = threading.Lock()


class MpcController(Controller):
    """Shared receding-horizon logic; subclasses choose the prediction model."""

    def __init__(self, config: MpcConfig | None = None) -> None:
        self.config = config or MpcConfig()
        super().__init__(self.config.params, self.config.limits)
        self.horizon_steps = self.config.horizon_steps
        self.dt_s = self.config.dt_s
        self.qp, new_step, self.qp_solver_used = self._shared_problem()
        self.rti = new_step()
        # The last solution (relative to _plan_origin) lives in rti.plan, which the step
        # Function shifts; _has_plan says whether there is one.
        self._has_plan = False
        self._plan_origin = np.zeros(3)
        self._plan_age = 0  # control steps since the plan was computed
        # The parameter blocks step writes every control step, looked up once.
        inputs = self.rti.inputs
        self._origin, self._x0, self._u_applied = (
            inputs["origin"],
            inputs["x0"],
            inputs["u_applied"],
        )
        self._x_ref, self._u_ref = inputs["x_ref"], inputs["u_ref"]
        # x_ref and u_ref are adjacent in the buffer: one finiteness check covers both.
        self._references = self.rti.blocks("x_ref", "u_ref")

    def _shared_problem(self) -> tuple[StageQp, Callable[[], StepBuffers], str]:
        """This problem's QP, a maker of step buffers for it and the QP solver's name, built
        once per process (~0.1 s of CasADi work under the interpreter's lock, which episode
        threads would otherwise each pay) and shared by its controllers: the QP and the
        compiled functions are never changed after building; each controller gets its own
        buffers and work areas."""
        key = json.dumps(
            [type(self).__module__, type(self).__qualname__, self.name, self.config.as_dict()],
            sort_keys=True,
            default=str,
        )
        with _PROBLEMS_LOCK:
            if key not in _PROBLEMS:
                qp = StageQp(self.prediction_model(), self.config, self.name)
                _PROBLEMS[key] = (qp, *self._step_maker(qp))
            return _PROBLEMS[key]

    def _step_maker(self, qp: StageQp) -> tuple[Callable[[], StepBuffers], str]:
        """The configured QP solver, or HPIPM (with one warning) where the Riccati solver
        cannot be compiled and ``compile`` allows it."""
        compile_mode = self.config.compile
        if self.config.qp_solver == "riccati" and compile_mode != "never":
            try:
                riccati = build_riccati_step(qp, self.name)
                return (lambda: RiccatiStep(qp, riccati)), "riccati"
            except SolverBuildError as error:
                if compile_mode == "always":
                    raise
                warnings.warn(
                    f"{error}; {self.name} solves its QP with HPIPM instead",
                    RuntimeWarning,
                    stacklevel=4,
                )
        hpipm = build_hpipm_step(qp, compile_mode, self.name)
        return (lambda: HpipmStep(qp, hpipm)), "hpipm"

    @abstractmethod
    def prediction_model(self) -> ca.Function:
        """The discrete model ``x+ = F(x, u)`` the controller predicts with."""

    @property
    def _plan(self) -> NDArray[np.float64] | None:
        """The last solution (a view of the step Function's plan buffer), if any."""
        return self.rti.plan if self._has_plan else None

    def reset(self) -> None:
        super().reset()
        self._has_plan = False
        self._plan_age = 0

    def settings(self) -> dict[str, Any]:
        return {
            **super().settings(),
            **self.config.as_dict(),
            "compiled": self.rti.compiled,
            "qp_solver_used": self.qp_solver_used,
        }

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
        yaw_ref = float(reference.yaw_rad[0])
        if not math.isfinite(yaw_ref):
            yaw_ref = state.yaw_rad
        # The references go into the parameter buffer first and are checked there (a step
        # with invalid inputs leaves the buffer to the next step, which rewrites all of it).
        self._x_ref[:] = reference.states[: n + 1]
        self._u_ref[:] = reference.inputs[:n]
        inputs_ok = state.is_finite() and np.isfinite(self._references).all()
        inputs_ok = inputs_ok and np.isfinite(obstacles.positions_m).all()
        if not inputs_ok:
            return self._fallback(start, 0, "invalid_input", yaw_ref)
        rti, origin = self.rti, self._origin
        origin[0], origin[1], origin[2] = state.x_m, state.y_m, state.z_m
        self._x0[:] = state.model_values()
        self._u_applied[:] = self.previous_input
        self._obstacle_slots(obstacles, origin)
        shift = self._warm_start(origin)
        iterations = 0
        solved = False
        # Controllers of one problem share its Functions (and their HPIPM workspaces and
        # stats): the solves take the process's native-code lock themselves, so that
        # controllers stepped from several threads never run them at once, whoever calls.
        with NATIVE_CALLS:
            for _ in range(self.config.sqp_iterations):
                try:
                    ok, qp_iterations = rti.solve(shift)
                except RuntimeError:  # CasADi reports solver crashes this way
                    ok, qp_iterations = False, 0
                iterations += max(qp_iterations, 0)
                if not ok:
                    break
                solved = True
                # The shifted guess stays in the Function: the first iterate always goes on.
                change = np.inf if shift else float(np.max(np.abs(rti.w - rti.guess)))
                rti.guess[:] = rti.w
                shift = False
                if change < self.config.sqp_step_tolerance:
                    break
        if not solved:
            return self._fallback(start, iterations, "", yaw_ref)
        rti.plan[:] = rti.guess
        self._has_plan, self._plan_age = True, 0
        self._plan_origin[:] = origin
        solution = rti.plan
        u = self.clipped_values(
            float(solution[NZ]), float(solution[NZ + 1]), float(solution[NZ + 2])
        )
        slack = float(solution[self.qp.slack_index].max(initial=0.0))
        status = "solved_soft" if slack > SLACK_TOLERANCE else "solved"
        elapsed_ms = (time.perf_counter() - start) * 1e3
        # Outside the timed part: the predicted path, back in absolute ENU, for the logs.
        predicted = solution[self.qp.position_index].reshape(-1, 3)
        predicted += origin
        return self.command(u, yaw_ref, SolveStats(elapsed_ms, iterations, status), predicted)

    def _obstacle_slots(self, obstacles: ObstacleForecast, origin: NDArray[np.float64]) -> None:
        """The nearest ``max_obstacles`` obstacles at steps 1..N, radii and active flags, into
        the parameter buffer; an empty slot sits at the origin (relative zero)."""
        n, m = self.horizon_steps, self.config.max_obstacles
        if not m:
            return
        inputs = self.rti.inputs
        positions, keep_out, active = inputs["obstacles"], inputs["keep_out"], inputs["active"]
        count = min(obstacles.count, m)
        if count:
            future = obstacles.positions_m[:, : n + 1, :]
            radii = obstacles.keep_out_radius_m
            if obstacles.count > m:  # keep the m that come nearest over the horizon
                # The ufunc and method forms skip the argument handling of np.min and np.argsort.
                margin = np.minimum.reduce(row_norms(future[:, 1:] - origin), axis=1) - radii
                chosen = margin.argsort(kind="stable")[:m]
                future, radii = future[chosen], radii[chosen]
            # The slots are interchangeable in the QP: with room for all, no ordering.
            positions[:count] = future[:, 1:]
            keep_out[:count] = self._sampled_radii(radii, future)
        active[:count] = 1.0
        if count < m:  # empty slots (writing empty slices costs as much as full ones)
            positions[count:] = origin
            keep_out[count:] = 0.0
            active[count:] = 0.0

    def _sampled_radii(
        self, radii: NDArray[np.float64], future: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """The radii the constraint keeps each predicted sample out of, so that the path
        between samples keeps out of ``radii + obstacle_margin_m`` too.

        The constraint holds at the samples only, and the drone flies on between them: at
        12 m/s a 0.1 s step is 1.2 m, and a path whose samples keep out of a sphere cut
        0.11 m into it between them. A straight step of length ``L`` whose two ends lie
        outside a sphere of radius ``sqrt(R^2 + (L/2)^2)`` stays outside radius ``R``
        (the nearest a chord comes to the centre); ``L`` is bounded by the reference's
        top speed plus the obstacle's over one step (``future``: its forecast positions).
        At 2 m/s the added radius is a centimetre or less; at the harness's 12 m/s
        cruise it is about 0.13 m (1.55 m becomes 1.68 m).
        """
        dt = self.dt_s
        reference_speed = float(row_norms(self._x_ref[:, 3:6]).max())
        obstacle_speed = np.maximum.reduce(row_norms(np.diff(future, axis=1)), axis=1) / dt
        half_step = 0.5 * dt * (reference_speed + obstacle_speed)
        wanted = radii + self.config.obstacle_margin_m
        return np.sqrt(wanted * wanted + half_step * half_step)

    def _warm_start(self, origin: NDArray[np.float64]) -> bool:
        """Prepare the initial guess: ``True`` when the step Function is to shift the plan by
        one step itself (the usual case); else a guess is written into ``rti.guess`` (a hover
        guess, or the plan shifted by several steps after fallbacks)."""
        rti, stage = self.rti, self.qp.stage
        if self._has_plan and self._plan_age == 0:
            rti.warm[:3] = self._plan_origin - origin
            return True
        first = np.concatenate([rti.inputs["x0"], self.previous_input])
        first[:3] -= origin
        if not self._has_plan:
            guess = np.zeros((self.horizon_steps + 1, stage))
            guess[:, :NZ] = first
            guess[:, NZ : NZ + NU] = self.previous_input
            rti.guess[:] = guess.ravel()[: self.qp.n_w]
            return False
        plan = rti.plan.copy()
        plan[self.qp.position_index] += np.tile(self._plan_origin - origin, self.horizon_steps + 1)
        shift = min(self._plan_age + 1, self.horizon_steps)
        # Drop the stages already flown; repeat the last input and state to fill the horizon.
        rti.guess[:] = np.concatenate([plan[shift * stage :], np.tile(plan[-stage:], shift)])
        return False

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
    """The paper's NMPC: the nonlinear model, SQP real-time iterations (each QP solved by
    the toolkit's Riccati interior point method, HPIPM where it stalls or where chosen)."""

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
