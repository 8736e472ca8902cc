"""Benchmark: our NMPC against a naive CasADi Opti + IPOPT formulation and do-mpc, one run.

The scenario (the one the project's NMPC notes measured): N = 20, dt = 0.1 s, the paper's
model, the same cost weights and input limits, a sinusoidal reference at about 0.5 m/s, two spheres
(r_obs 0.4 m + r_s 0.3 m) crossing it at 0.3 m/s when the drone passes, 200 closed-loop
steps on the same plant. Each set-up flies it through :class:`skyvln_eval.control.Flight`,
and the step time is the wall time of the whole ``Controller.step``, timed from outside
(packing and the command included; each set-up first flies 10 untimed steps on the same
controller, which the timed flight resets),
the RMSE is the position error against the reference, and the clearance is the distance to
the obstacle centres minus ``r_obs + r_s`` (negative = inside a keep-out sphere).

Rows: ours (SQP real-time iteration: shift and linearisation in one compiled CasADi call,
the QP solved by the compiled Riccati interior point method of ``control/stage_ipm.py``;
the default), ours with HPIPM inside the CasADi call instead (compiled, and interpreted:
what runs without a C compiler), ours iterated to convergence (evidence for the RTI choice),
the linear MPC, the naive Opti + IPOPT baseline (zero initial guess every step, hard
constraints, IPOPT defaults) and do-mpc (its defaults: collocation, IPOPT with MUMPS; it
has no per-step input-rate bound, only the rate penalty). Aims: our median at most 0.3 ms,
p95 at most 0.6 ms, max at most 1.5 ms, no failed steps, clearance never below zero, RMSE
under 0.2 m, at least 300x faster than the naive baseline at the median.

    PYTHONPATH=. python benchmarks/nmpc.py [--steps 200] [--skip naive,do-mpc]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core per solver, as on the robot

import argparse
import importlib.util
import time
import warnings
from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np

from skyvln_eval.control import Command, Controller, Flight, MpcConfig, SolveStats
from skyvln_eval.control.codegen import blasfeo_instruction_sets
from skyvln_eval.control.mpc import LinearMpcController, NmpcController
from skyvln_eval.sim import (
    ConstantVelocity,
    DroneState,
    ObstacleForecast,
    ObstacleScenario,
    ReferenceTrajectory,
    ReferenceWindow,
    SphereObstacle,
    model_rhs,
    rk4_symbolic,
)

N, DT = 20, 0.1
WARM_UP_STEPS = 10
CONFIG = MpcConfig()  # the weights and limits every set-up uses
PARAMS, LIMITS, WEIGHTS = CONFIG.params, CONFIG.limits, CONFIG.weights


def reference() -> ReferenceTrajectory:
    """x = 0.5 t, y = sin(0.4 t), z = 1 + 0.2 sin(0.3 t), heading 0."""

    def path(t: np.ndarray) -> tuple[np.ndarray, ...]:
        z0 = np.zeros_like(t)
        p = np.stack([0.5 * t, np.sin(0.4 * t), 1.0 + 0.2 * np.sin(0.3 * t)], axis=1)
        v = np.stack([0.5 + z0, 0.4 * np.cos(0.4 * t), 0.06 * np.cos(0.3 * t)], axis=1)
        a = np.stack([z0, -0.16 * np.sin(0.4 * t), -0.018 * np.sin(0.3 * t)], axis=1)
        return p, v, a

    return ReferenceTrajectory(path, lambda t: np.zeros(len(t)), 1e9, PARAMS)


def scenario(obstacles: bool = True) -> ObstacleScenario:
    """Two spheres crossing the reference at 0.3 m/s as the drone passes (t = 6 s and 13 s),
    their centres 0.3 m ahead of the reference point then: well inside the 0.7 m keep-out
    radius, so the drone has to swerve (by about 0.4 m) for each."""
    if not obstacles:
        return ObstacleScenario("none")
    window = reference().window(np.array([6.0, 13.0]))
    crossing = []
    for (x, y, z), direction, meet_s in zip(
        window.position_m, (1.0, -1.0), (6.0, 13.0), strict=True
    ):
        velocity = (0.0, 0.3 * direction, 0.0)
        start = (x + 0.3, y - velocity[1] * meet_s, z)
        crossing.append(SphereObstacle(ConstantVelocity(start, velocity), 0.4, 0.3))
    return ObstacleScenario("two_crossing_spheres", tuple(crossing))


def _cost(x: Any, u: Any, u_prev: Any, x_ref: Any, u_ref: Any) -> Any:
    e_x, e_u, du = x_ref - x, u_ref - u, u - u_prev
    q_x, q_u, q_du = (ca.diag(ca.DM(w)) for w in (WEIGHTS.state, WEIGHTS.input, WEIGHTS.input_rate))
    return ca.bilin(q_x, e_x, e_x) + ca.bilin(q_u, e_u, e_u) + ca.bilin(q_du, du, du)


class NaiveOptiIpopt(Controller):
    """The textbook formulation: Opti, hard constraints, IPOPT defaults, zero initial guess."""

    name = "opti_ipopt"
    horizon_steps = N
    dt_s = DT

    def __init__(self) -> None:
        super().__init__(PARAMS, LIMITS)
        opti = self.opti = ca.Opti()
        self.x, self.u = opti.variable(8, N + 1), opti.variable(3, N)
        self.x0, self.u_prev = opti.parameter(8), opti.parameter(3)
        self.x_ref, self.u_ref = opti.parameter(8, N + 1), opti.parameter(3, N)
        self.obs = [opti.parameter(3, N + 1) for _ in range(2)]
        self.keep_out = opti.parameter(2)
        model, d_max = rk4_symbolic(PARAMS, DT), LIMITS.tilt_ref_step_max_rad
        cost = 0
        opti.subject_to(self.x[:, 0] == self.x0)
        for k in range(N):
            previous = self.u_prev if k == 0 else self.u[:, k - 1]
            cost += _cost(self.x[:, k], self.u[:, k], previous, self.x_ref[:, k], self.u_ref[:, k])
            opti.subject_to(self.x[:, k + 1] == model(self.x[:, k], self.u[:, k]))
            opti.subject_to(
                opti.bounded(LIMITS.thrust_min_m_s2, self.u[0, k], LIMITS.thrust_max_m_s2)
            )
            opti.subject_to(
                opti.bounded(-LIMITS.tilt_ref_max_rad, self.u[1:, k], LIMITS.tilt_ref_max_rad)
            )
            opti.subject_to(opti.bounded(-d_max, self.u[1:, k] - previous[1:], d_max))
            for i in range(2):
                gap = self.x[:3, k + 1] - self.obs[i][:, k + 1]
                opti.subject_to(self.keep_out[i] ** 2 - ca.sumsqr(gap) <= 0)
        e_n = self.x_ref[:, N] - self.x[:, N]
        opti.minimize(cost + ca.bilin(ca.diag(ca.DM(WEIGHTS.state)), e_n, e_n))
        opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})

    def step(
        self, state: DroneState, reference: ReferenceWindow, obstacles: ObstacleForecast
    ) -> Command:
        start = time.perf_counter()
        opti = self.opti
        opti.set_value(self.x0, state.model_vector())
        opti.set_value(self.u_prev, self.previous_input)
        opti.set_value(self.x_ref, reference.states.T)
        opti.set_value(self.u_ref, reference.inputs[:N].T)
        for i in range(2):
            opti.set_value(self.obs[i], obstacles.positions_m[i].T)
        opti.set_value(self.keep_out, obstacles.keep_out_radius_m)
        try:
            solution = opti.solve()  # every variable starts at 0: no warm start
            u, status, failed = np.asarray(solution.value(self.u[:, 0])).ravel(), "solved", False
        except RuntimeError:
            u, status, failed = self.safe_input(), "fallback_hover", True
        iterations = int(opti.stats().get("iter_count", -1))
        stats = SolveStats((time.perf_counter() - start) * 1e3, iterations, status, failed)
        return self.command(self.clip_input(u), float(reference.yaw_rad[0]), stats)


class DoMpc(Controller):
    """do-mpc with its defaults (orthogonal collocation, IPOPT + MUMPS), same cost and limits."""

    name = "do_mpc"
    horizon_steps = N
    dt_s = DT

    def __init__(self) -> None:
        import do_mpc

        super().__init__(PARAMS, LIMITS)
        model = do_mpc.model.Model("continuous")
        x = model.set_variable("_x", "x", shape=(8, 1))
        u = model.set_variable("_u", "u", shape=(3, 1))
        x_ref = model.set_variable("_tvp", "x_ref", shape=(8, 1))
        u_ref = model.set_variable("_tvp", "u_ref", shape=(3, 1))
        obstacles = [model.set_variable("_tvp", f"obs{i}", shape=(3, 1)) for i in range(2)]
        keep_out = model.set_variable("_tvp", "keep_out", shape=(2, 1))
        model.set_rhs("x", ca.vertcat(*model_rhs(x, u, PARAMS)))
        model.setup()
        mpc = self.mpc = do_mpc.controller.MPC(model)
        mpc.settings.n_horizon, mpc.settings.t_step = N, DT
        mpc.settings.store_full_solution = False
        mpc.settings.supress_ipopt_output()
        e_x, e_u = x_ref - x, u_ref - u
        q_x, q_u = ca.diag(ca.DM(WEIGHTS.state)), ca.diag(ca.DM(WEIGHTS.input))
        mpc.set_objective(
            lterm=ca.bilin(q_x, e_x, e_x) + ca.bilin(q_u, e_u, e_u), mterm=ca.bilin(q_x, e_x, e_x)
        )
        mpc.set_rterm(u=np.array(WEIGHTS.input_rate))
        low = [LIMITS.thrust_min_m_s2, -LIMITS.tilt_ref_max_rad, -LIMITS.tilt_ref_max_rad]
        high = [LIMITS.thrust_max_m_s2, LIMITS.tilt_ref_max_rad, LIMITS.tilt_ref_max_rad]
        mpc.bounds["lower", "_u", "u"], mpc.bounds["upper", "_u", "u"] = low, high
        for i, obstacle in enumerate(obstacles):
            mpc.set_nl_cons(f"sphere{i}", keep_out[i] ** 2 - ca.sumsqr(x[:3] - obstacle), ub=0.0)
        template = mpc.get_tvp_template()
        self._window: tuple[ReferenceWindow, ObstacleForecast] | None = None

        def tvp(t_now: float) -> Any:
            if self._window is None:  # do-mpc checks the template once at set-up
                return template
            window, forecast = self._window
            for k in range(N + 1):
                template["_tvp", k, "x_ref"] = window.states[k]
                template["_tvp", k, "u_ref"] = window.inputs[min(k, N - 1)]
                for i in range(2):
                    template["_tvp", k, f"obs{i}"] = forecast.positions_m[i, k]
                template["_tvp", k, "keep_out"] = forecast.keep_out_radius_m
            return template

        mpc.set_tvp_fun(tvp)
        mpc.setup()
        self._started = False

    def step(
        self, state: DroneState, reference: ReferenceWindow, obstacles: ObstacleForecast
    ) -> Command:
        start = time.perf_counter()
        x0 = state.model_vector().reshape(-1, 1)
        self._window = (reference, obstacles)
        if not self._started:
            self.mpc.x0 = x0
            self.mpc.u0 = self.previous_input.reshape(-1, 1)
            self.mpc.set_initial_guess()
            self._started = True
        u = np.asarray(self.mpc.make_step(x0)).ravel()
        stats_ = self.mpc.solver_stats
        failed = not bool(stats_.get("success", False))
        stats = SolveStats(
            (time.perf_counter() - start) * 1e3,
            int(stats_.get("iter_count", -1)),
            "solved" if not failed else str(stats_.get("return_status", "failed")),
            failed,
        )
        # Clipped to the rate limit, which do-mpc cannot impose itself: what would be flown.
        return self.command(self.clip_input(u), float(reference.yaw_rad[0]), stats)


def fly(controller: Controller, steps: int, obstacles: bool = True) -> dict[str, float]:
    """Fly the scenario; each step timed from outside, around the whole ``Controller.step``
    (a controller's own ``solve_time_ms`` may leave out what it does after the solve:
    ours stops its clock before it builds the command and the predicted path). Also the
    CPU time of each step: on a shared machine the wall time includes the time the
    scheduler gave to other processes, the CPU time does not."""
    wall_ms: list[float] = []
    cpu_ms: list[float] = []
    step = controller.step

    def timed(*args: Any) -> Command:
        start, start_cpu = time.perf_counter(), time.thread_time()
        command = step(*args)
        cpu_ms.append((time.thread_time() - start_cpu) * 1e3)
        wall_ms.append((time.perf_counter() - start) * 1e3)
        return command

    controller.step = timed  # type: ignore[method-assign,assignment]
    try:
        flight = Flight(controller, DroneState(0.0, 0.0, 1.0), scenario=scenario(obstacles))
        log = flight.fly(reference(), duration_s=steps * DT).log
    finally:
        del controller.step  # the class's own again, for the next flight
    error = np.linalg.norm(
        log[["x_m", "y_m", "z_m"]].to_numpy() - log[["ref_x_m", "ref_y_m", "ref_z_m"]].to_numpy(),
        axis=1,
    )
    times = np.array(wall_ms)
    return {
        "median": float(np.median(times)),
        "p95": float(np.percentile(times, 95)),
        "max": float(times.max()),
        "rmse": float(np.sqrt(np.mean(error**2))),
        "clearance": float(log.min_clearance_m.min()),
        "failed": int(log.solve_failed.sum()),
        "iterations": float(log.iterations.median()),
        "cpu_median": float(np.median(cpu_ms)),
        "cpu_max": float(np.max(cpu_ms)),
    }


Setup = tuple[str, str, Callable[[], Controller], bool]


def setups(skip: set[str]) -> list[Setup]:
    rows: list[Setup] = [
        ("ours", "NMPC: SQP-RTI, Riccati IPM (C)", lambda: NmpcController(CONFIG), True),
        ("ours_free", "NMPC: same, no obstacles (tracking)", lambda: NmpcController(CONFIG), False),
        (
            "ours_hpipm",
            "NMPC: same, HPIPM in the CasADi call",
            lambda: NmpcController(MpcConfig(qp_solver="hpipm")),
            True,
        ),
        (
            "ours_interpreted",
            "NMPC: same, HPIPM interpreted",
            lambda: NmpcController(MpcConfig(qp_solver="hpipm", compile="never")),
            True,
        ),
        (
            "ours_converged",
            "NMPC: SQP to convergence (<= 10 it.)",
            lambda: NmpcController(MpcConfig(sqp_iterations=10)),
            True,
        ),
        ("linear_mpc", "linear MPC (hover model)", lambda: LinearMpcController(CONFIG), True),
        ("naive", "naive Opti + IPOPT, zero guess", NaiveOptiIpopt, True),
    ]
    if importlib.util.find_spec("do_mpc") is not None:
        rows.append(("do-mpc", "do-mpc defaults", DoMpc, True))
    else:
        print("do-mpc is not installed: its row is left out (pip install do-mpc)")
    return [row for row in rows if row[0] not in skip]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--skip", default="", help="comma-separated row keys to leave out")
    args = parser.parse_args()
    warnings.filterwarnings("ignore", module="do_mpc")  # its optional-feature notices
    warnings.filterwarnings("ignore", category=FutureWarning, module="casadi")  # do-mpc's numpy use
    load = os.getloadavg()
    print(
        f"{os.cpu_count()} CPUs, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
        f"N = {N}, dt = {DT} s, {args.steps} steps, two spheres crossing at 0.3 m/s"
    )
    sets = blasfeo_instruction_sets()
    kind = "unknown" if sets is None else sets or "none: the generic C build"
    print(f"instruction sets of the BLASFEO under HPIPM (the QP's linear algebra): {kind}")
    results: dict[str, dict[str, float]] = {}
    header = (
        f"{'set-up':38} {'build s':>7} {'median ms':>9} {'p95':>7} {'max':>7} {'cpu med':>7} "
        f"{'cpu max':>7} {'iter':>4} {'RMSE m':>6} {'clear m':>7} {'failed':>6}"
    )
    print(header)
    for key, label, make, obstacles in setups(set(filter(None, args.skip.split(",")))):
        start = time.perf_counter()
        controller = make()
        build_s = time.perf_counter() - start
        # Warm-up: every set-up first flies 10 untimed steps on the very controller that is
        # timed (the first calls fault in pages and fill caches, and Opti builds its IPOPT
        # solver at its first solve: on another instance, the naive row's max was that
        # one-time set-up), then the timed flight, which starts with a reset.
        fly(controller, WARM_UP_STEPS, obstacles)
        r = results[key] = fly(controller, args.steps, obstacles)
        print(
            f"{label:38} {build_s:7.2f} {r['median']:9.3f} {r['p95']:7.3f} {r['max']:7.3f} "
            f"{r['cpu_median']:7.3f} {r['cpu_max']:7.3f} {r['iterations']:4.0f} {r['rmse']:6.3f} "
            f"{r['clearance']:7.3f} {r['failed']:6d}"
        )
    ours = results.get("ours")
    if ours is None:
        return
    for key in ("naive", "do-mpc", "ours_converged", "ours_hpipm", "ours_interpreted"):
        if key in results:
            median_ratio = results[key]["median"] / ours["median"]
            max_ratio = results[key]["max"] / ours["max"]
            print(
                f"ours vs {key}: {_speed(median_ratio)} at the median, {_speed(max_ratio)} at "
                "the max"
            )
    checks = {
        "median <= 0.3 ms": ours["median"] <= 0.3,
        "p95 <= 0.6 ms": ours["p95"] <= 0.6,
        "max <= 1.5 ms": ours["max"] <= 1.5,
        "CPU max <= 1.5 ms": ours["cpu_max"] <= 1.5,
        "no failed steps": ours["failed"] == 0,
        "clearance >= 0": ours["clearance"] >= 0.0,
        "RMSE < 0.2 m": ours["rmse"] < 0.2,
    }
    if "naive" in results:
        checks[">= 300x faster than naive"] = results["naive"]["median"] / ours["median"] >= 300.0
    print("aims: " + ", ".join(f"{name}: {'yes' if ok else 'NO'}" for name, ok in checks.items()))
    load = os.getloadavg()
    print(f"load average after: {load[0]:.2f} (timings are wall time on a shared machine)")


def _speed(ratio: float) -> str:
    """``3.0x faster`` or, under 1, ``2.0x slower``: a ratio below 1 never reads as faster."""
    return f"{ratio:.1f}x faster" if ratio >= 1.0 else f"{1.0 / ratio:.1f}x slower"


if __name__ == "__main__":
    main()
