"""The paper's MPC problem in the stage-wise layout, as one QP linearised at a guess.

Decision variables, stage by stage (the order HPIPM requires):
``w = [z_0, v_0, z_1, v_1, ..., z_{N-1}, v_{N-1}, z_N]`` with the augmented state
``z = [x, u_prev]`` (the model state plus the previously applied input, folded in so the
rate limits couple one stage only) and the stage controls ``v = [u, s]`` (the model input
plus, when there are obstacle slots, one slack shared by that stage's sphere constraints:
one per stage rather than one per obstacle keeps the QP small, and an L1 penalty on it is
still exact). Rows, stage by stage: the gap-closing rows first, then
that stage's path constraints. With ``p_{k+1} = F_p(x_k, u_k)`` the predicted position:

    min  sum_{k=0..N} ||x_ref,k - x_k||^2_Qx + sum_{k=0..N-1} ||u_ref,k - u_k||^2_Qu
                                              + ||u_k - u_prev,k||^2_Qdu + rho1 s_k + rho2 s_k^2
    s.t. x_{k+1} = F(x_k, u_k)                                 (the model, one RK4 step)
         u_prev,k+1 = u_k
         z_0 = [measured x, applied u]
         T_min <= T_k <= T_max
         |roll_ref,k| <= tilt_max,   |pitch_ref,k| <= tilt_max
         |roll_ref,k - roll_ref_prev,k| <= d_tilt_max
         |pitch_ref,k - pitch_ref_prev,k| <= d_tilt_max
         (r_obs,i + r_s,i)^2 - ||p_{k+1} - p_obs,i,k+1||^2 <= s_k,   s_k >= 0

The cost is quadratic in ``w`` (squares of linear terms plus the slack penalty), so its
Hessian is constant: the Gauss-Newton Hessian is exact for the cost and ignores only the
constraints' curvature. Linearising ``g(w)`` at a guess ``w_bar`` gives a QP in ``w``.
``||p - p_obs||^2`` is convex, so its linearisation under-estimates it everywhere: the
linearised sphere constraint is a half-space outside the keep-out sphere, and whatever the
guess, a position the QP predicts is outside the sphere (up to the linearised dynamics).
Positions are relative to an origin chosen by the caller (the drone's position), which
keeps the numbers small and the squared distances well scaled.

HPIPM settings, measured on the benchmark scenario (``benchmarks/nmpc.py``): the CasADi
interface bounds every variable (infinite bounds become +-``inf``, so that is kept small);
warm-starting from the shifted plan with a large initial barrier ``mu0`` cuts the interior
point iterations from about 12 to 5 at the same solution (first input within 1e-3 rad of a
1e-8-tolerance solve, median 1e-8), and residual tolerances of 1e-6 suffice for the metres
and radians of this problem.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from skyvln_eval.control.mpc_config import MpcConfig
from skyvln_eval.control.stage_blocks import hessian_blocks, stage_blocks
from skyvln_eval.sim.quadrotor import NU, NX

NZ = NX + NU  # augmented state [x, u_prev]

HPIPM_OPTIONS: dict[str, Any] = {
    "mode": "speed_abs",
    "iter_max": 50,
    "warm_start": 1,
    "mu0": 1e2,
    "res_g_max": 1e-6,
    "res_b_max": 1e-6,
    "res_d_max": 1e-6,
    "res_m_max": 1e-6,
}


class StageQp:
    """The QP data function (linearisation at a guess) and the HPIPM solver, built once.

    :class:`~skyvln_eval.control.rti.RtiStep` puts both into one Function per control step.
    """

    def __init__(self, dynamics: ca.Function, config: MpcConfig, name: str) -> None:
        self.config = config
        n, m = config.horizon_steps, config.max_obstacles
        self.n_v = NU + (1 if m else 0)
        self.stage = NZ + self.n_v
        self.n_w = n * self.stage + NZ
        #: Constraint rows per stage: the model and memory rows, the rate limits, the spheres.
        self.rows_per_stage = NZ + 2 + m
        starts = self.stage * np.arange(n + 1)
        #: Where in ``w`` the positions of every stage, and the slacks, are.
        self.position_index = (starts[:, None] + np.arange(3)).ravel()
        self.slack_index = (starts[:n, None] + NZ + np.arange(NU, self.n_v)).ravel()
        self.n_p = NX + NU + (n + 1) * NX + n * NU + m * n * 3 + 2 * m
        w = ca.SX.sym("w", self.n_w)
        p = ca.SX.sym("p", self.n_p)
        cost, rows, lower, upper = self._problem(w, p, dynamics)
        lbx, ubx = self._bounds(p)

        # The QP at a guess w_bar: g(w) ~ g(w_bar) + A (w - w_bar), so A w in [lb - b, ub - b].
        jac = ca.jacobian(rows, w)
        offset = rows - ca.mtimes(jac, w)
        hessian, gradient = ca.hessian(cost, w)
        if ca.depends_on(hessian, ca.vertcat(w, p)):
            raise RuntimeError("the MPC cost is not quadratic in w: its Hessian is not constant")
        self.hessian = ca.DM(ca.evalf(hessian))
        linear = ca.substitute(gradient, w, ca.DM.zeros(self.n_w))
        #: The same QP stage by stage, in the layout of the Riccati solver (:mod:`.stage_ipm`):
        #: ``problem(w, p)`` the linearised blocks, :attr:`hessian_blocks` the cost's Hessian.
        self.problem = ca.Function(
            f"{name}_qp_blocks",
            [w, p],
            [stage_blocks(self, jac, offset, lower, upper, linear, lbx, ubx)],
            ["w", "p"],
            ["problem"],
            {"cse": True},
        )
        self.hessian_blocks = hessian_blocks(self, self.hessian)
        self.data = ca.Function(
            f"{name}_qp_data",
            [w, p],
            [linear, jac, lower - offset, upper - offset, lbx, ubx],
            ["w", "p"],
            ["g", "a", "lba", "uba", "lbx", "ubx"],
            {"cse": True},
        )
        self.solver = ca.conic(
            f"{name}_hpipm",
            "hpipm",
            {"h": self.hessian.sparsity(), "a": jac.sparsity()},
            {
                "N": n,
                "nx": [NZ] * (n + 1),
                "nu": [self.n_v] * n + [0],
                "ng": [2 + m] * n + [0],
                "error_on_fail": False,
                "inf": 1e4,
                "hpipm": HPIPM_OPTIONS,
            },
        )

    def _problem(self, w: ca.SX, p: ca.SX, dynamics: ca.Function) -> tuple[Any, ...]:
        """The cost and the constraint rows ``lower <= rows(w) <= upper``, stage by stage."""
        cfg, weights, limits = self.config, self.config.weights, self.config.limits
        n, m = cfg.horizon_steps, cfg.max_obstacles
        x_ref, u_ref, obstacles, keep_out, active = self._unpack_references(p)
        q_x, q_u = ca.diag(ca.DM(weights.state)), ca.diag(ca.DM(weights.input))
        q_du = ca.diag(ca.DM(weights.input_rate))
        d_tilt = limits.tilt_ref_step_max_rad
        rows: list[Any] = []
        lower: list[Any] = []
        upper: list[Any] = []

        def constrain(row: Any, low: Any, high: Any) -> None:
            rows.append(row)
            lower.append(low)
            upper.append(high)

        cost = ca.SX(0)
        for k in range(n + 1):
            x, u_prev = self._z(w, k)[:NX], self._z(w, k)[NX:]
            e_x = x_ref[k] - x
            cost += (weights.terminal_scale if k == n else 1.0) * ca.bilin(q_x, e_x, e_x)
            if k == n:
                break
            u, slack = self._v(w, k)[:NU], self._v(w, k)[NU:]
            e_u, du = u_ref[k] - u, u - u_prev
            cost += ca.bilin(q_u, e_u, e_u) + ca.bilin(q_du, du, du)
            cost += weights.slack_linear * ca.sum1(slack)
            cost += weights.slack_quadratic * ca.sumsqr(slack)
            x_next = dynamics(x, u)
            z_next = self._z(w, k + 1)
            # Gap-closing rows first (the model, then the input memory), then the path rows.
            constrain(x_next - z_next[:NX], ca.DM.zeros(NX), ca.DM.zeros(NX))
            constrain(u - z_next[NX:], ca.DM.zeros(NU), ca.DM.zeros(NU))
            constrain(u[1] - u_prev[1], -d_tilt, d_tilt)  # |roll_ref,k - roll_ref,k-1| <= d
            constrain(u[2] - u_prev[2], -d_tilt, d_tilt)  # |pitch_ref,k - pitch_ref,k-1| <= d
            for i in range(m):
                # (r_obs + r_s)^2 - ||p_{k+1} - p_obs,i||^2 <= s_k; an empty slot is unbounded.
                distance_sq = ca.sumsqr(x_next[:3] - obstacles[i][k])
                needed = ca.if_else(active[i] > 0.5, keep_out[i] ** 2, -ca.inf)
                constrain(distance_sq + slack[0], needed, ca.inf)
        return cost, ca.vertcat(*rows), ca.vertcat(*lower), ca.vertcat(*upper)

    def _bounds(self, p: ca.SX) -> tuple[ca.SX, ca.SX]:
        limits, n = self.config.limits, self.config.horizon_steps
        x0, u_applied = p[:NX], p[NX : NX + NU]
        u_low = [limits.thrust_min_m_s2, -limits.tilt_ref_max_rad, -limits.tilt_ref_max_rad]
        u_high = [limits.thrust_max_m_s2, limits.tilt_ref_max_rad, limits.tilt_ref_max_rad]
        v_low = ca.DM(u_low + [0.0] * (self.n_v - NU))
        v_high = ca.DM(u_high + [ca.inf] * (self.n_v - NU))
        free = ca.DM.inf(NZ)
        lbx: list[Any] = [x0, u_applied, v_low, *[-free, v_low] * (n - 1), -free]
        ubx: list[Any] = [x0, u_applied, v_high, *[free, v_high] * (n - 1), free]
        return ca.vertcat(*lbx), ca.vertcat(*ubx)

    def _unpack_references(
        self, p: ca.SX
    ) -> tuple[list[ca.SX], list[ca.SX], list[list[ca.SX]], ca.SX, ca.SX]:
        n, m = self.config.horizon_steps, self.config.max_obstacles
        offset = NX + NU
        x_ref = [p[offset + k * NX : offset + (k + 1) * NX] for k in range(n + 1)]
        offset += (n + 1) * NX
        u_ref = [p[offset + k * NU : offset + (k + 1) * NU] for k in range(n)]
        offset += n * NU
        obstacles = [
            [p[offset + (i * n + k) * 3 : offset + (i * n + k + 1) * 3] for k in range(n)]
            for i in range(m)
        ]
        offset += m * n * 3
        return x_ref, u_ref, obstacles, p[offset : offset + m], p[offset + m : offset + 2 * m]

    def _z(self, w: ca.SX, k: int) -> ca.SX:
        return w[k * self.stage : k * self.stage + NZ]

    def _v(self, w: ca.SX, k: int) -> ca.SX:
        return w[k * self.stage + NZ : (k + 1) * self.stage]
