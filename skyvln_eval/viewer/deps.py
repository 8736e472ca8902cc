"""The optional Rerun dependency, imported only when a recording is built or served.

``import skyvln_eval`` never imports Rerun (a 200 MB wheel); :func:`rerun_sdk` imports it
on first use and says which extra to install when it is missing.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from types import ModuleType

from skyvln_eval.errors import MissingExtraError

EXTRA = "viewer"


def rerun_sdk() -> ModuleType:
    """The ``rerun`` module (``pip install 'skyvln-eval[viewer]'``)."""
    try:
        import rerun
    except ImportError as error:
        raise MissingExtraError("skyvln-eval view", EXTRA, f"rerun-sdk: {error}") from error
    return rerun


def rerun_cli_path() -> Path:
    """The ``rerun`` executable that the rerun-sdk wheel ships (``rerun rrd``, ``--serve-web``).

    The console script of the same name is a Python wrapper that starts this binary as a
    child; running the binary itself lets the toolkit stop exactly the process it started.
    ``$RERUN_CLI_PATH`` overrides it, as it does for that wrapper.
    """
    if override := os.environ.get("RERUN_CLI_PATH"):
        return Path(override)
    try:
        import rerun_cli
    except ImportError as error:
        found = shutil.which("rerun")
        if found is None:
            raise MissingExtraError("the rerun command", EXTRA, str(error)) from error
        return Path(found)
    binary = Path(rerun_cli.__file__).parent / "rerun"
    if not binary.is_file():
        raise MissingExtraError("the rerun command", EXTRA, f"no binary at {binary}")
    return binary
