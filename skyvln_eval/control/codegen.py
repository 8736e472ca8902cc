"""Compiled CasADi functions, cached on disk across processes and runs.

Generating C for an MPC's step function and compiling it with ``gcc -O3`` takes 10-25 s,
so a library is built once per problem and machine and kept under ``cache_root()/casadi``.
The key hashes everything that can change the compiled code: the CasADi version, the
compiler (its path and its ``--version`` line) and flags, the revision of our patches to the
generated code, and the generated C source itself (about 50 ms to produce), so any change
of model, cost, constraint, weight, horizon or solver option is a new key. (The function's
serialised form is not enough: it leaves out the options of an embedded QP solver, so a
changed HPIPM option used to load the library built with the old one.)

Processes that need the same library at the same time (the workers of a run) take a file
lock, so one of them builds and the others load its result: a machine never compiles a
problem twice (the compile, lock and cache steps are :mod:`skyvln_eval.cbuild`'s). A
broken or half-written cache entry never breaks a run: it is rebuilt, and if that fails
too the interpreted function is used.
Without a C compiler the functions run interpreted and a one-line warning says so once
per process.

Functions that embed HPIPM (the structured QP solver) are linked against the HPIPM and
BLASFEO libraries of the CasADi wheel. Two additions to the generated source make the
compiled solver behave as the interpreted one (see :func:`_patch_hpipm`).
"""

from __future__ import annotations

import ctypes
import logging
import re
import subprocess
import warnings
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from skyvln_eval.cbuild import build_lock, compile_library, compiler, compiler_identity, digest
from skyvln_eval.control.mpc_config import CompileMode
from skyvln_eval.errors import SolverBuildError
from skyvln_eval.paths import cache_root

log = logging.getLogger(__name__)

CFLAGS = ("-O3", "-fPIC", "-shared")
#: Changes whenever :func:`_patch_hpipm` changes what it does to the generated code.
PATCH_REVISION = "hpipm-patch-1"
#: Name suffix of the exported function that returns the last QP's iteration count.
ITERATIONS_SYMBOL = "_qp_iterations"
_warned_no_compiler = False


@dataclass(frozen=True)
class Compiled:
    """A function to call, whether it is compiled, the library it came from and whether that
    library was built by this call (rather than found in the cache)."""

    function: ca.Function
    compiled: bool
    library: Path | None = None
    built_now: bool = False


def casadi_dir() -> Path:
    """The CasADi package folder: its headers and the HPIPM / BLASFEO libraries."""
    return Path(ca.__file__).parent


def blasfeo_instruction_sets() -> str | None:
    """The instruction sets of the BLASFEO that CasADi's HPIPM runs its linear algebra on,
    as that library reports them (e.g. ``"AVX AVX2 FMA"``; ``""`` for a generic C build),
    or ``None`` if there is no such library to ask. Most of a solve's time is spent there:
    the CasADi wheel's generic build runs the NMPC's QP about half as fast as one built for
    the CPU (measured; see ``benchmarks/nmpc.py``)."""
    # Asked through HPIPM's own library: a symbol looked up there comes from the BLASFEO
    # it loads (its dependency), whichever of the files beside it that is.
    for path in sorted(casadi_dir().glob("libhpipm*")):
        try:
            library = ctypes.CDLL(str(path))
            describe = library.blasfeo_processor_library_string
        except (OSError, AttributeError):
            continue
        text = ctypes.create_string_buffer(256)
        describe(text)
        return text.value.decode(errors="replace").strip()
    return None


def generated_source(function: ca.Function) -> str:
    """The C code CasADi generates for ``function`` (before our patches)."""
    generator = ca.CodeGenerator(f"{function.name()}.c", {"with_header": False})
    generator.add(function)
    return str(generator.dump())


def cache_key(source: str, cc: str) -> str:
    """The library's key: CasADi and compiler versions, flags, patch revision, source."""
    return digest(
        (ca.CasadiMeta.version(), compiler_identity(cc), " ".join(CFLAGS), PATCH_REVISION, source)
    )


def maybe_compile(function: ca.Function, mode: CompileMode) -> Compiled:
    """``function`` compiled to C (from the cache or built now), or itself when not possible."""
    global _warned_no_compiler
    if mode == "never":
        return Compiled(function, False)
    cc = compiler()
    if cc is None:
        if mode == "always":
            raise SolverBuildError("no C compiler found ($CC or gcc) and compile='always' was set")
        if not _warned_no_compiler:
            warnings.warn(
                "no C compiler found ($CC or gcc): MPC functions run interpreted (slower)",
                RuntimeWarning,
                stacklevel=2,
            )
            _warned_no_compiler = True
        return Compiled(function, False)
    name = function.name()
    source = generated_source(function)
    library = cache_root() / "casadi" / f"{name}-{cache_key(source, cc)}.so"
    try:
        with build_lock(library):
            loaded = _load(name, library)
            built_now = loaded is None
            if loaded is None:
                _build(name, source, cc, library)
                loaded = _load(name, library, rebuild_on_error=False)
        if loaded is None:
            raise RuntimeError(f"the library built for {name} cannot be loaded")
        return Compiled(loaded, True, library, built_now)
    except (OSError, RuntimeError, subprocess.CalledProcessError) as error:
        if mode == "always":
            raise SolverBuildError(f"compiling {name} failed: {error}") from error
        warnings.warn(
            f"compiling {name} failed ({error}); running it interpreted",
            RuntimeWarning,
            stacklevel=2,
        )
        return Compiled(function, False)


def qp_iterations_reader(compiled: Compiled) -> Callable[[], int] | None:
    """The exported ``<name>_qp_iterations()`` of a compiled function embedding HPIPM."""
    if compiled.library is None:
        return None
    try:
        reader = getattr(
            ctypes.CDLL(str(compiled.library)), compiled.function.name() + ITERATIONS_SYMBOL
        )
    except (OSError, AttributeError):
        return None
    reader.restype = ctypes.c_int
    reader.argtypes = []
    return reader


class NativeCall:
    """A compiled function called straight through its C entry point, with the caller's
    arrays as its inputs and outputs and its own work arrays.

    ctypes releases the interpreter's lock for the call (CasADi's ``FunctionBuffer`` holds
    it), so other threads run Python meanwhile. The generated code keeps no state between
    calls besides the per-thread iteration count of :func:`_patch_hpipm`: everything it
    needs is in the work arrays, one set per caller.
    """

    def __init__(
        self,
        compiled: Compiled,
        inputs: Sequence[NDArray[np.float64]],
        outputs: Sequence[NDArray[np.float64]],
    ) -> None:
        if compiled.library is None:
            raise ValueError("NativeCall needs a compiled library")
        name = compiled.function.name()
        library = ctypes.CDLL(str(compiled.library))
        sizes = [ctypes.c_longlong() for _ in range(4)]  # casadi_int is long long
        work = getattr(library, f"{name}_work")
        work.restype = ctypes.c_int
        work(*(ctypes.byref(size) for size in sizes))
        n_arg, n_res, n_iw, n_w = (size.value for size in sizes)
        for array in (*inputs, *outputs):
            if array.dtype != np.float64 or not array.flags.c_contiguous:
                raise ValueError(f"{name}: arguments must be contiguous float64 arrays")
        self._keep = (*inputs, *outputs)  # the pointers below point into these
        self._iw = np.zeros(max(n_iw, 1), dtype=np.int64)
        self._w = np.zeros(max(n_w, 1))
        pointers = [array.ctypes.data for array in inputs] + [None] * (n_arg - len(inputs))
        results = [array.ctypes.data for array in outputs] + [None] * (n_res - len(outputs))
        self._arg = (ctypes.c_void_p * max(n_arg, 1))(*pointers)
        self._res = (ctypes.c_void_p * max(n_res, 1))(*results)
        self._function = getattr(library, name)
        self._function.restype = ctypes.c_int
        self._function.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        checkout = getattr(library, f"{name}_checkout")
        checkout.restype = ctypes.c_int
        self._mem = int(checkout())
        if self._mem < 0:
            raise RuntimeError(f"{name}: no memory to check out")
        release = getattr(library, f"{name}_release")
        release.argtypes = [ctypes.c_int]
        weakref.finalize(self, release, self._mem)
        self._call = (
            ctypes.addressof(self._arg),
            ctypes.addressof(self._res),
            self._iw.ctypes.data,
            self._w.ctypes.data,
            self._mem,
        )

    def __call__(self) -> int:
        """Run the function; its return code (0: success)."""
        code: int = self._function(*self._call)
        return code


def _load(name: str, library: Path, rebuild_on_error: bool = True) -> ca.Function | None:
    if not library.exists():
        return None
    try:
        return ca.external(name, str(library))
    except RuntimeError as error:  # a truncated or foreign file: rebuild it
        if not rebuild_on_error:
            raise
        log.warning("rebuilding unusable compiled library %s: %s", library, error)
        return None


def _build(name: str, text: str, cc: str, library: Path) -> None:
    """Compile the generated C ``text`` of function ``name`` to ``library``."""
    link: list[str] = []
    if "hpipm_d_ocp_qp_ipm.h" in text:
        text = _patch_hpipm(text, name)
        folder = casadi_dir()
        link = [
            f"-I{folder / 'include'}",
            f"-L{folder}",
            "-lhpipm",
            "-lblasfeo",
            f"-Wl,-rpath,{folder}",
        ]
    compile_library(name, text, cc, CFLAGS, library, link)


def _patch_hpipm(text: str, name: str) -> str:
    """Two additions to CasADi's generated HPIPM call (checked with CasADi 3.8).

    1. The generated code fills the solver's option struct field by field on the stack but
       leaves five fields of the HPIPM version in the wheel unset (``dual_gap_max``,
       ``lam0_min``, ``t0_min``, ``t0_init``, ``update_fact_exit``); uninitialised, they made
       solves fail at random under ``-O2``. The interpreted solver starts from HPIPM's
       defaults for the mode and then sets its options: so does the patched code.
    2. The iteration count of the last solve, per thread, readable through the exported
       ``<name>_qp_iterations()`` (the generated function has no output for it).
    """
    options = re.search(r"^([ \t]*)(\w+)\.hpipm_options\.mu0 = ", text, re.MULTILINE)
    mode = re.search(r"\.hpipm_options\.mode = (\d+);", text)
    includes = list(re.finditer(r"^#include .*$", text, re.MULTILINE))
    if options is None or mode is None or not includes:
        raise RuntimeError("unexpected HPIPM code from CasADi: cannot patch it")
    indent, prob = options.group(1), options.group(2)
    defaults = (
        f"{indent}d_ocp_qp_ipm_arg_set_default((enum hpipm_mode) {mode.group(1)}, "
        f"&{prob}.hpipm_options);\n"
    )
    text = text[: options.start()] + defaults + text[options.start() :]
    text, calls = re.subn(
        r"^([ \t]*)(\w+_hpipm_solve\(&(\w+), arg, res, iw, w\);)$",
        r"\1\2\n\1skyvln_qp_iterations = \3.iter_count;",
        text,
        flags=re.MULTILINE,
    )
    if calls != 1:
        raise RuntimeError(f"expected one HPIPM call in the generated code, found {calls}")
    counter = (
        "\nstatic __thread int skyvln_qp_iterations = -1;\n"
        f"int {name}{ITERATIONS_SYMBOL}(void) {{ return skyvln_qp_iterations; }}\n"
    )
    cut = includes[-1].end()
    return text[:cut] + counter + text[cut:]
