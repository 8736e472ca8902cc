"""One MPC control step in compiled code: shift, linearise, solve the structured QP.

Per control step Python crosses into compiled code once or twice. A step Function takes

- ``plan``: the previous solution (relative to the origin it was computed in),
- ``guess``: a ready initial guess, used instead of the shifted plan when ``warm[3]`` is 0
  (the hover guess of a first step, or a plan shifted by several steps after fallbacks),
- ``params``: :data:`PARAM_LAYOUT` in absolute ENU metres, with the new origin first,
- ``warm``: ``[plan origin - new origin (3), shift flag]``,

and inside it shifts the plan one step (repeating the last stage) and re-expresses it in
the new origin, puts the measured state and the applied input in the first stage, moves
every position to the new origin and linearises the problem at the guess
(:class:`~skyvln_eval.control.stage_qp.StageQp`). Two ways to solve the QP:

- :class:`RiccatiStep` (the default): the Function writes the QP stage by stage
  (:mod:`.stage_blocks`) and the compiled Riccati interior point method
  (:mod:`.stage_ipm`) solves it;
- :class:`HpipmStep`: the Function also solves the QP with HPIPM (CasADi's interface),
  and runs interpreted where there is no C compiler.

Compiled, a Function's C entry point is called through ctypes on preallocated numpy arrays
(:class:`~skyvln_eval.control.codegen.NativeCall`): no argument conversion, no allocation,
and the interpreter's lock released, so other episode threads run meanwhile.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.control.codegen import (
    Compiled,
    NativeCall,
    maybe_compile,
    qp_iterations_reader,
)
from skyvln_eval.control.mpc_config import CompileMode
from skyvln_eval.control.stage_ipm import SOLVED, Sizes, StageIpm, load_library
from skyvln_eval.control.stage_qp import NZ, StageQp
from skyvln_eval.sim.quadrotor import NU, NX

#: Blocks of the ``params`` input, in order (N = horizon steps, M = obstacle slots).
PARAM_LAYOUT = (
    ("origin", "(3,) the positions' origin (the drone's position)"),
    ("x0", "(8,) the measured model state"),
    ("u_applied", "(3,) the input applied last step"),
    ("x_ref", "(N + 1, 8) reference states, now and N steps ahead"),
    ("u_ref", "(N, 3) reference inputs"),
    ("obstacles", "(M, N, 3) obstacle centres at steps 1..N (an empty slot at the origin)"),
    ("keep_out", "(M,) keep-out radii"),
    ("active", "(M,) 1 for a filled obstacle slot"),
)


class StepBuffers(ABC):
    """The buffers of one controller's step: fill :attr:`inputs` (views into the parameter
    buffer, one per :data:`PARAM_LAYOUT` block), :attr:`plan` or :attr:`guess`, then call
    :meth:`solve`; the solution is in :attr:`w`."""

    compiled: bool

    def __init__(self, qp: StageQp) -> None:
        self.qp = qp
        shapes = _param_shapes(qp)
        sizes = [int(np.prod(shape)) for shape in shapes.values()]
        self.params = np.zeros(sum(sizes))
        ends = np.cumsum(sizes)
        #: Writable views into the parameter buffer, by block name.
        self.inputs: dict[str, NDArray[np.float64]] = {
            key: self.params[end - size : end].reshape(shape)
            for (key, shape), size, end in zip(shapes.items(), sizes, ends, strict=True)
        }
        self._spans = {
            key: (int(end - size), int(end))
            for key, size, end in zip(shapes, sizes, ends, strict=True)
        }
        self.plan = np.zeros(qp.n_w)
        self.guess = np.zeros(qp.n_w)
        self.warm = np.zeros(4)
        self.w = np.zeros(qp.n_w)

    def blocks(self, first: str, last: str) -> NDArray[np.float64]:
        """A flat view of the parameter buffer from block ``first`` to block ``last``
        (inclusive, in :data:`PARAM_LAYOUT` order)."""
        return self.params[self._spans[first][0] : self._spans[last][1]]

    @abstractmethod
    def solve(self, shift: bool) -> tuple[bool, int]:
        """Run the step: from the shifted :attr:`plan` (``shift``) or from :attr:`guess`.
        Returns whether the QP was solved and its iteration count."""


class RiccatiStep(StepBuffers):
    """The QP written stage by stage by a compiled Function and solved by the compiled
    Riccati interior point method (:mod:`.stage_ipm`): two native calls per step.

    A QP it cannot solve (about 1 in 4,000 of a flight past obstacles with a random agent:
    it stalls on nearly degenerate constraints) is solved again by HPIPM through CasADi,
    interpreted (a few milliseconds); :attr:`hpipm_solves` counts them."""

    compiled = True

    def __init__(self, qp: StageQp, built: RiccatiBuild) -> None:
        super().__init__(qp)
        self.problem = np.zeros(built.sizes.problem_doubles)
        self.start = np.zeros(qp.n_w)
        self.qp_parameters = np.zeros(qp.n_p)
        self._blocks = NativeCall(
            built.blocks,
            (self.plan, self.guess, self.params, self.warm),
            (self.problem, self.start, self.qp_parameters),
        )
        self.solver = StageIpm(load_library(built.sizes), built.sizes, qp.hessian_blocks)
        self.solver.bind(self.problem, self.start, self.w)
        self._hpipm = built.hpipm
        self.hpipm_solves = 0

    def solve(self, shift: bool) -> tuple[bool, int]:
        self.warm[3] = 1.0 if shift else 0.0
        if self._blocks() != 0:
            return False, 0
        status, iterations = self.solver()
        if status not in SOLVED:
            self.hpipm_solves += 1
            solution = self._hpipm(self.start, self.qp_parameters)
            self.w[:] = np.asarray(solution[0]).ravel()
            stats = self._hpipm.stats()
            iterations += int(stats.get("iter_count", 0))
            return bool(stats.get("success")) and bool(np.isfinite(self.w).all()), iterations
        return bool(np.isfinite(self.w).all()), iterations


@dataclass(frozen=True)
class RiccatiBuild:
    """What the Riccati steps of one problem share: the compiled blocks Function, the
    solver's sizes and the interpreted HPIPM solve of the same QP (the fall-back)."""

    blocks: Compiled
    sizes: Sizes
    hpipm: ca.Function


def build_riccati_step(qp: StageQp, name: str) -> RiccatiBuild:
    """The compiled blocks Function of ``qp``, the solver's sizes (the solver library is
    built or loaded here too, so a missing compiler shows now) and the fall-back. Raises
    :class:`~skyvln_eval.errors.SolverBuildError` when either cannot be compiled."""
    inputs, start, p = step_inputs(qp)
    function = ca.Function(
        f"{name}_rti_blocks",
        inputs,
        [qp.problem(start, p), start, p],
        ["plan", "guess", "params", "warm"],
        ["problem", "start", "p"],
    )
    compiled = maybe_compile(function, "always")
    sizes = Sizes(
        horizon=qp.config.horizon_steps,
        states=NX,
        inputs=NU,
        slacks=qp.n_v - NU,
        rows=qp.rows_per_stage - NZ,
    )
    load_library(sizes)
    at, parameters = ca.MX.sym("start", qp.n_w), ca.MX.sym("p", qp.n_p)
    return RiccatiBuild(compiled, sizes, _hpipm_solve(qp, f"{name}_hpipm_qp", at, parameters))


class HpipmStep(StepBuffers):
    """The step Function of one :class:`StageQp` with HPIPM inside (compiled or
    interpreted), with its buffers."""

    def __init__(self, qp: StageQp, built: Compiled) -> None:
        """Buffers for ``built`` (:func:`build_hpipm_step` of ``qp``), which controllers of the
        same problem share: each has its own buffers, and its own memory in the Function."""
        super().__init__(qp)
        self._lam_a = np.zeros(qp.solver.size1_in("lam_a0"))
        self._lam_x = np.zeros(qp.n_w)
        self.function, self.compiled = built.function, built.compiled
        self._iterations = qp_iterations_reader(built)
        # Compiled, the step runs through its C entry point on these arrays (in place: they
        # must stay the same objects), with the interpreter's lock released.
        self._native: NativeCall | None = None
        if self.compiled:
            self._native = NativeCall(
                built,
                (self.plan, self.guess, self.params, self.warm),
                (self.w, self._lam_a, self._lam_x),
            )

    def solve(self, shift: bool) -> tuple[bool, int]:
        self.warm[3] = 1.0 if shift else 0.0
        if self._native is not None:
            ok = self._native() == 0
            iterations = self._iterations() if self._iterations is not None else -1
        else:
            out = self.function(self.plan, self.guess, self.params, self.warm)
            self.w[:] = np.asarray(out[0]).ravel()
            stats = self.function.stats()
            ok, iterations = bool(stats.get("success")), int(stats.get("iter_count", -1))
        return ok and bool(np.isfinite(self.w).all()), iterations


def build_hpipm_step(qp: StageQp, compile_mode: CompileMode, name: str) -> Compiled:
    """The HPIPM step Function of ``qp``, compiled (or cached, or interpreted) as
    ``compile_mode`` says; build it once per problem and process (about 0.1 s)."""
    return maybe_compile(_step_function(qp, name), compile_mode)


def _param_shapes(qp: StageQp) -> dict[str, tuple[int, ...]]:
    n, m = qp.config.horizon_steps, qp.config.max_obstacles
    return {
        "origin": (3,),
        "x0": (NX,),
        "u_applied": (NU,),
        "x_ref": (n + 1, NX),
        "u_ref": (n, NU),
        "obstacles": (m, n, 3),
        "keep_out": (m,),
        "active": (m,),
    }


def step_inputs(qp: StageQp) -> tuple[list[ca.MX], ca.MX, ca.MX]:
    """The inputs of a step Function (``plan``, ``guess``, ``params``, ``warm``) and, from
    them, the point to linearise at and the QP's parameter vector: the warm start (the plan's
    positions moved to the new origin and shifted one stage, or the ready guess) with the
    measured state and applied input as its first stage, every position relative to the
    origin."""
    sizes = [int(np.prod(shape)) for shape in _param_shapes(qp).values()]
    n_w, stage = qp.n_w, qp.stage
    plan, guess = ca.MX.sym("plan", n_w), ca.MX.sym("guess", n_w)
    params, warm = ca.MX.sym("params", sum(sizes)), ca.MX.sym("warm", 4)
    blocks = ca.vertsplit(params, [0, *np.cumsum(sizes).tolist()])
    origin, x0, u_applied, x_ref, u_ref, obstacles, keep_out, active = blocks
    n, m = qp.config.horizon_steps, qp.config.max_obstacles
    # Every position relative to the origin: the problem's numbers stay small.
    state_origin = ca.vertcat(origin, ca.DM.zeros(NX - 3))
    x0_rel = x0 - state_origin
    x_ref_rel = ca.reshape(x_ref, NX, n + 1) - ca.repmat(state_origin, 1, n + 1)
    obstacles_rel = ca.reshape(obstacles, 3, m * n) - ca.repmat(origin, 1, m * n)
    p = ca.vertcat(
        x0_rel, u_applied, ca.vec(x_ref_rel), u_ref, ca.vec(obstacles_rel), keep_out, active
    )
    # The warm start: the plan's positions moved to the new origin, shifted one stage.
    rows = qp.position_index
    to_positions = ca.DM(
        ca.Sparsity.triplet(n_w, 3, rows.tolist(), (np.arange(len(rows)) % 3).tolist()),
        1.0,
    )
    moved = plan + ca.mtimes(to_positions, warm[:3])
    shifted = ca.vertcat(moved[stage:], moved[n_w - stage :])
    chosen = ca.if_else(warm[3], shifted, guess)
    start = ca.vertcat(x0_rel, u_applied, chosen[NZ:])
    return [plan, guess, params, warm], start, p


def _hpipm_solve(qp: StageQp, name: str, start: ca.MX, p: ca.MX) -> ca.Function:
    """``(start, p) -> (w, lam_a, lam_x)``: the QP linearised at ``start`` solved by HPIPM.
    The multipliers are outputs because CasADi's HPIPM interface writes them whether they
    are asked for or not (without them, it writes through a null pointer)."""
    solution = _hpipm_solution(qp, start, p)
    outputs = [solution["x"], solution["lam_a"], solution["lam_x"]]
    return ca.Function(name, [start, p], outputs, ["start", "p"], ["w", "lam_a", "lam_x"])


def _hpipm_solution(qp: StageQp, start: ca.MX, p: ca.MX) -> dict[str, ca.MX]:
    g, a, lba, uba, lbx, ubx = qp.data(start, p)
    solution: dict[str, ca.MX] = qp.solver(
        h=qp.hessian,
        g=g,
        a=a,
        lba=lba,
        uba=uba,
        lbx=lbx,
        ubx=ubx,
        x0=start,
        lam_x0=ca.DM.zeros(qp.n_w),
        lam_a0=ca.DM.zeros(qp.solver.size1_in("lam_a0")),
    )
    return solution


def _step_function(qp: StageQp, name: str) -> ca.Function:
    inputs, start, p = step_inputs(qp)
    solution = _hpipm_solution(qp, start, p)
    return ca.Function(
        f"{name}_rti",
        inputs,
        [solution["x"], solution["lam_a"], solution["lam_x"]],
        ["plan", "guess", "params", "warm"],
        ["w", "lam_a", "lam_x"],
    )
