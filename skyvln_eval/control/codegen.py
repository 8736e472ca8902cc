"""Compiled CasADi functions, cached on disk by a hash of the problem definition.

Generating C for an MPC's functions and compiling it with ``gcc -O3`` takes 10-25 s and
makes each call several times faster, so a compiled library is built once per problem and
kept under ``cache_root()/casadi``. The key hashes everything that can change the compiled
code: the CasADi version, the compiler and its flags, and the function itself (its
serialised expression graph, so any change of model, cost, constraint, weight or horizon
is a new key). A broken or half-written cache entry never breaks a run: it is rebuilt, and
if that fails too the interpreted function is used. Without a C compiler the functions run
interpreted and a warning says so once per process.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

from skyvln_eval.control.mpc_config import CompileMode
from skyvln_eval.errors import SolverBuildError
from skyvln_eval.paths import cache_root

log = logging.getLogger(__name__)

CFLAGS = ("-O3", "-fPIC", "-shared")
_warned_no_compiler = False


def compiler() -> str | None:
    """The C compiler to use (``$CC``, else ``gcc``), or ``None`` if there is none."""
    return shutil.which(os.environ.get("CC", "gcc"))


def cache_key(function: ca.Function, cc: str) -> str:
    digest = hashlib.sha256()
    for part in (ca.CasadiMeta.version(), Path(cc).name, " ".join(CFLAGS), function.serialize()):
        digest.update(part.encode() + b"\0")
    return digest.hexdigest()[:20]


def maybe_compile(function: ca.Function, mode: CompileMode) -> tuple[ca.Function, bool]:
    """``function`` compiled to C (from the cache or built now), or itself when not possible.

    Returns the function to call and whether it is compiled.
    """
    global _warned_no_compiler
    if mode == "never":
        return function, False
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
        return function, False
    name = function.name()
    library = cache_root() / "casadi" / f"{name}-{cache_key(function, cc)}.so"
    if library.exists():
        try:
            return ca.external(name, str(library)), True
        except RuntimeError as error:  # a truncated or foreign file: rebuild it
            log.warning("rebuilding unusable compiled library %s: %s", library, error)
    try:
        _build(function, cc, library)
        return ca.external(name, str(library)), True
    except (OSError, RuntimeError, subprocess.CalledProcessError) as error:
        if mode == "always":
            raise SolverBuildError(f"compiling {name} failed: {error}") from error
        warnings.warn(
            f"compiling {name} failed ({error}); running it interpreted",
            RuntimeWarning,
            stacklevel=2,
        )
        return function, False


def _build(function: ca.Function, cc: str, library: Path) -> None:
    """Generate C for ``function`` and compile it to ``library`` (temporary name, then rename)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent, prefix=".build-") as build:
        source = f"{function.name()}.c"
        generator = ca.CodeGenerator(source, {"with_header": False})
        generator.add(function)
        generator.generate(build + os.sep)
        built = Path(build) / library.name
        log.info("compiling %s with %s (once per problem definition)", function.name(), cc)
        subprocess.run(
            [cc, *CFLAGS, "-o", str(built), str(Path(build) / source), "-lm"],
            check=True,
            capture_output=True,
        )
        built.replace(library)
