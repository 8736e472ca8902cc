"""The MPC's QP solver: an interior point method with a Riccati recursion, compiled from C.

``native/stage_ipm.c`` solves the stage-wise QP of :class:`~.stage_qp.StageQp` (in the
layout of :mod:`.stage_blocks`) by Mehrotra's predictor-corrector: each iteration is one
Riccati factorisation of the Newton system, stage by stage, and two solves with it. It is
built for the problem's sizes (horizon, obstacle slots), so every loop has a fixed length,
and it multiplies only the model's blocks of the dynamics (the input memory's rows are
known by their shape). Measured on the benchmark scenario's 200 QPs (``benchmarks/nmpc.py``)
against HPIPM as CasADi sets it up, on the same QPs and the same residual tolerance: 5.1
iterations on average where HPIPM takes 6.3, about 0.03 ms per iteration where HPIPM's
(on the CasADi wheel's generic BLASFEO) takes about 0.1, and closer to the QP's exact
solution (every variable within 2e-5 of a 1e-11 solve, where HPIPM's first inputs were off
by up to 8e-3). It stalls on a few nearly degenerate QPs (a box bound and a linearised
sphere at the first stage swapping which one is active): about 1 in 4,000 QPs of flights
with a random agent, which :class:`~.rti.RiccatiStep` then solves with HPIPM.

The library is compiled with the system's C compiler on first use and cached on disk
(:mod:`skyvln_eval.cbuild`; key: source, sizes, flags, compiler). On x86-64 the entry point
is built twice, for AVX2 + FMA and for the baseline, and the loader picks the one the CPU
runs. The C function keeps no state: each caller passes its own work area, and ctypes
releases the interpreter's lock while it runs.
"""

from __future__ import annotations

import ctypes
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.cbuild import cached_library, compiler
from skyvln_eval.errors import SolverBuildError

SOURCE: Final = Path(__file__).with_name("native") / "stage_ipm.c"
CFLAGS: Final = ("-O3", "-fPIC", "-shared")

#: Residual tolerance (stationarity, dynamics, inequalities, complementarity), as HPIPM's.
TOLERANCE: Final = 1e-6
#: Initial barrier: slacks start at max(c(guess), T0_MIN) and multipliers at MU0 / slack.
#: Measured on the benchmark's 200 QPs (with a fraction to the boundary of 0.995): MU0 1e2
#: with T0_MIN 1e-2 takes 5.3 iterations on average (10 at most), 1e1 takes 8.5 and 1e3
#: 6.0; a T0_MIN of 1e-1 takes 10.3.
MU0: Final = 1e2
T0_MIN: Final = 1e-2
MAX_ITERATIONS: Final = 50
#: The least fraction of the longest step to the boundary of the positive orthant that is
#: taken; the fraction is max(BOUNDARY, 1 - mu), so it tends to 1 as the method converges.
#: On the benchmark's QPs: 5.1 iterations on average (5.3 with a fixed 0.995, 6.0 with
#: 0.99). A fixed 0.999 took 4.5 but stalled on QPs of flights past obstacles (9 of 15,000).
BOUNDARY: Final = 0.995
#: When the method stops short of TOLERANCE (the iteration limit, or a factorisation lost to
#: rounding: the barrier weights of nearly degenerate constraints grow without bound and
#: hold the stationarity residual near 1e-6), its best iterate is the solution if every
#: residual is within this (3 of 41,000 QPs of 90 flights with random agents).
ACCEPTABLE: Final = 1e-4

#: Return codes of ``stage_ipm_solve``: 0 and 4 are solutions.
STATUS: Final = {
    0: "solved",
    1: "iteration limit",
    2: "non-finite",
    3: "not positive definite",
    4: "solved to the acceptable residual",
}
SOLVED: Final = frozenset({0, 4})


@dataclass(frozen=True)
class Sizes:
    """The compile-time sizes of one problem."""

    horizon: int
    states: int
    inputs: int
    slacks: int
    rows: int  # general rows per stage (rate limits and spheres)

    def defines(self) -> tuple[str, ...]:
        values = (self.horizon, self.states, self.inputs, self.slacks, self.rows)
        return tuple(
            f"-D{name}={value}"
            for name, value in zip(("SN", "SX", "SU", "SS", "SG"), values, strict=True)
        )

    @property
    def problem_doubles(self) -> int:
        nz, nv, sx, su, sg = (
            self.states + self.inputs,
            self.inputs + self.slacks,
            self.states,
            self.inputs,
            self.rows,
        )
        per_stage = sx * sx + sx * su + sx + sg * nz + sg * nv + 2 * sg + 3 * nv + nz
        return self.horizon * per_stage + nz

    @property
    def hessian_doubles(self) -> int:
        nz, nv = self.states + self.inputs, self.inputs + self.slacks
        return self.horizon * (nv * nv + nv * nz + nz * nz) + nz * nz


class StageIpm:
    """The compiled solver for one problem's sizes, with a work area (one per caller)."""

    def __init__(self, library: ctypes.CDLL, sizes: Sizes, hessian: NDArray[np.float64]) -> None:
        for name, expected in (
            ("stage_ipm_problem_size", sizes.problem_doubles),
            ("stage_ipm_hessian_size", sizes.hessian_doubles),
        ):
            reported = getattr(library, name)
            reported.restype = ctypes.c_long
            if reported() != 8 * expected:
                raise SolverBuildError(
                    f"{SOURCE.name}: {name} is {reported()} bytes, expected {8 * expected}"
                )
        if hessian.shape != (sizes.hessian_doubles,):
            raise ValueError(
                f"the Hessian has {hessian.size} numbers, expected {sizes.hessian_doubles}"
            )
        work_size = library.stage_ipm_work_size
        work_size.restype = ctypes.c_long
        self.sizes = sizes
        self._hessian = np.ascontiguousarray(hessian, dtype=np.float64)
        self._work = np.zeros(int(work_size()) // 8 + 1)
        #: ``[tolerance, mu0, t0_min, max iterations, least fraction to the boundary,
        #: acceptable residual]``, read at every call (tests lower the iteration limit).
        self.settings = np.array([TOLERANCE, MU0, T0_MIN, MAX_ITERATIONS, BOUNDARY, ACCEPTABLE])
        self._iterations = ctypes.c_int(0)
        self._solve = library.stage_ipm_solve
        self._solve.restype = ctypes.c_int
        self._solve.argtypes = [ctypes.c_void_p] * 7 + [ctypes.POINTER(ctypes.c_int)]

    def bind(
        self,
        problem: NDArray[np.float64],
        start: NDArray[np.float64],
        solution: NDArray[np.float64],
    ) -> None:
        """Fix the arrays :meth:`__call__` reads and writes (they must stay these objects):
        the problem data, the point it was linearised at (its first stage is the fixed
        state; the rest the primal guess) and where the solution goes, all as ``w``."""
        for array in (problem, start, solution):
            if array.dtype != np.float64 or not array.flags.c_contiguous:
                raise ValueError("stage_ipm arguments must be contiguous float64 arrays")
        if problem.size != self.sizes.problem_doubles:
            raise ValueError(
                f"problem has {problem.size} numbers, expected {self.sizes.problem_doubles}"
            )
        self._keep = (problem, start, solution)
        self._call = (
            self._hessian.ctypes.data,
            problem.ctypes.data,
            start.ctypes.data,  # z_0: the first stage of the start point
            start.ctypes.data,
            solution.ctypes.data,
            self._work.ctypes.data,
            self.settings.ctypes.data,
            ctypes.byref(self._iterations),
        )

    def __call__(self) -> tuple[int, int]:
        """Solve the bound problem: its status code (:data:`STATUS`) and iterations."""
        status: int = self._solve(*self._call)
        return status, self._iterations.value


_lock = threading.Lock()
_libraries: dict[Sizes, ctypes.CDLL] = {}


def load_library(sizes: Sizes) -> ctypes.CDLL:
    """The solver compiled for ``sizes`` (built once per machine, loaded once per process).
    Raises :class:`SolverBuildError` if there is no compiler or the build fails."""
    with _lock:
        if sizes in _libraries:
            return _libraries[sizes]
        cc = compiler()
        if cc is None:
            raise SolverBuildError("no C compiler found ($CC or gcc) for the MPC's QP solver")
        flags = (*CFLAGS, *sizes.defines())
        try:
            loaded = ctypes.CDLL(str(cached_library("stage_ipm", SOURCE.read_text(), cc, flags)))
        except (OSError, subprocess.CalledProcessError) as error:
            detail = getattr(error, "stderr", b"") or b""
            raise SolverBuildError(
                f"building the MPC's QP solver failed: {error} {detail.decode(errors='replace')}"
            ) from error
        _libraries[sizes] = loaded
        return loaded
