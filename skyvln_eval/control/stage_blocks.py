"""The MPC's QP stage by stage, in the layout of the Riccati solver (:mod:`.stage_ipm`).

:class:`~skyvln_eval.control.stage_qp.StageQp` linearises the problem into one QP over
``w = [z_0, v_0, ..., z_N]`` with a sparse constraint Jacobian. The Riccati solver takes
the same QP as blocks per stage ``k`` (each matrix column-major):

    Fx (NX x NX), Fu (NX x NU), f (NX)       x_{k+1} = Fx x_k + Fu u_k + f
    C (NG x NZ), D (NG x NV), lg, ug (NG)    lg <= C z_k + D v_k <= ug
    lv, uv (NV)                              lv <= v_k <= uv
    r (NV), q (NZ)                           the cost's linear terms

then ``q_N`` (NZ), and the constant Hessian as ``R (NV x NV), S (NV x NZ), Q (NZ x NZ)`` per
stage and ``Q_N``. The rows ``u_prev,k+1 = u_k`` of the input memory are not passed: the
solver knows them by their shape. Building the blocks checks that the QP has that shape
(only the model couples stages, the memory rows are exactly ``[I 0]``), so a change of
:class:`StageQp` that broke it fails when the problem is built, not in a flight.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.sim.quadrotor import NU, NX

if TYPE_CHECKING:
    from skyvln_eval.control.stage_qp import StageQp

NZ = NX + NU


def stage_blocks(
    qp: StageQp, jac: Any, offset: Any, lower: Any, upper: Any, linear: Any, lbx: Any, ubx: Any
) -> Any:
    """The solver's problem data as one SX column, from the linearised QP of ``qp``: the
    rows ``lower <= jac w + offset <= upper`` and the bounds ``lbx <= w <= ubx``."""
    n, stage = qp.config.horizon_steps, qp.stage
    n_g = qp.rows_per_stage - NZ
    _check_shape(qp, jac, offset)
    parts: list[Any] = []
    for k in range(n):
        row = k * qp.rows_per_stage
        z = slice(k * stage, k * stage + NZ)
        v = slice(k * stage + NZ, (k + 1) * stage)
        model, path = slice(row, row + NX), slice(row + NZ, row + NZ + n_g)
        parts += [
            _column(jac[model, z][:, :NX]),  # Fx
            _column(jac[model, v][:, :NU]),  # Fu
            offset[model],  # f
            _column(jac[path, z]),  # C
            _column(jac[path, v]),  # D
            lower[path] - offset[path],  # lg
            upper[path] - offset[path],  # ug
            lbx[v],
            ubx[v],
            linear[v],  # r
            linear[z],  # q
        ]
    parts.append(linear[n * stage : n * stage + NZ])  # q_N
    return ca.vertcat(*parts)


def hessian_blocks(qp: StageQp, hessian: ca.DM) -> NDArray[np.float64]:
    """The constant Hessian in the solver's layout (R, S, Q per stage, then Q_N)."""
    dense = np.asarray(hessian.full())
    n, stage = qp.config.horizon_steps, qp.stage
    outside = np.ones(dense.shape, dtype=bool)
    parts: list[NDArray[np.float64]] = []
    for k in range(n + 1):
        z = slice(k * stage, k * stage + NZ)
        if k == n:
            outside[z, z] = False
            parts.append(dense[z, z].ravel(order="F"))
            break
        v = slice(k * stage + NZ, (k + 1) * stage)
        outside[k * stage : (k + 1) * stage, k * stage : (k + 1) * stage] = False
        parts += [dense[v, v].ravel(order="F"), dense[v, z].ravel(order="F")]
        parts.append(dense[z, z].ravel(order="F"))
    if np.any(dense[outside]):
        raise RuntimeError("the MPC cost couples stages: the Riccati solver cannot take it")
    return np.ascontiguousarray(np.concatenate(parts))


def _column(block: Any) -> Any:
    """A block as one column, column-major, with its structural zeros written out."""
    return ca.vec(ca.densify(block))


def _check_shape(qp: StageQp, jac: Any, offset: Any) -> None:
    """Raise unless each stage's rows touch only its own variables (and ``z_{k+1}`` for the
    model and memory rows), the model rows ignore ``u_prev`` and the slacks, and the memory
    rows read ``u_prev,k+1 = u_k`` exactly."""
    n, stage = qp.config.horizon_steps, qp.stage
    rows, cols = jac.sparsity().get_triplet()
    for r, c in zip(rows, cols, strict=True):
        k, local = divmod(r, qp.rows_per_stage)
        own = k * stage <= c < (k + 1) * stage
        next_state = (k + 1) * stage <= c < (k + 1) * stage + NZ
        column = c - k * stage
        if local < NX:  # model rows: x_k, u_k and x_{k+1}
            ok = column < NX or NZ <= column < NZ + NU
            ok = ok or (next_state and c - (k + 1) * stage == local)
        elif local < NZ:  # memory rows: u_k and u_prev,k+1
            ok = column == NZ + local - NX or (next_state and c - (k + 1) * stage == local)
        else:
            ok = own
        if not ok:
            raise RuntimeError(
                f"MPC QP row {r} (stage {k}) has an entry in column {c}: not the stage shape "
                "the Riccati solver takes"
            )
    memory_and_next: list[Any] = []
    for k in range(n):
        row = k * qp.rows_per_stage
        nxt = slice((k + 1) * stage, (k + 1) * stage + NZ)
        memory = slice(row + NX, row + NZ)
        memory_and_next += [
            jac[memory, slice(k * stage + NZ, k * stage + NZ + NU)],
            jac[slice(row, row + NZ), nxt],
            offset[memory],
        ]
    values = [np.asarray(ca.evalf(ca.densify(block))) for block in memory_and_next]
    for k in range(n):
        input_block, next_block, offset_block = values[3 * k : 3 * k + 3]
        if not (
            np.array_equal(input_block, np.eye(NU))
            and np.array_equal(next_block, -np.eye(NZ))
            and not np.any(offset_block)
        ):
            raise RuntimeError(f"MPC QP stage {k}: the memory rows are not u_prev,k+1 = u_k")
