"""Where the bundled synthetic dataset lives, and building it on first use.

The sample is generated, not shipped: on first use it is built into the cache
(``$SKYVLN_EVAL_CACHE``, else ``$XDG_CACHE_HOME/skyvln-eval``, else
``~/.cache/skyvln-eval``) under a name that includes the generator and dialog versions and a hash of
the spec, in a temporary folder renamed into place when complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from skyvln_eval.fileio import rename_into_place
from skyvln_eval.paths import cache_root
from skyvln_eval.worlds.city.generate import GENERATOR_VERSION
from skyvln_eval.worlds.sample.build import DATASET_INFO, SPECS, DatasetSpec, build_dataset
from skyvln_eval.worlds.sample.dialogs import DIALOG_VERSION


def dataset_dir_name(spec: DatasetSpec) -> str:
    digest = hashlib.sha256(
        json.dumps({**asdict(spec), "records": dict(spec.records)}, sort_keys=True).encode()
    ).hexdigest()[:10]
    return f"{spec.name}-g{GENERATOR_VERSION}d{DIALOG_VERSION}-{digest}"


def is_complete(path: Path) -> bool:
    return (path / DATASET_INFO).is_file()


def ensure_dataset(
    spec: DatasetSpec | str = "sample",
    root: str | Path | None = None,
    workers: int = 1,
    force: bool = False,
    on_map_done: Callable[[str], None] | None = None,
) -> Path:
    """The folder of a synthetic dataset, building it first if it is not there yet."""
    spec = SPECS[spec] if isinstance(spec, str) else spec
    root = Path(root) if root is not None else cache_root()
    final = root / dataset_dir_name(spec)
    if is_complete(final) and not force:
        return final
    root.mkdir(parents=True, exist_ok=True)
    staging = root / f".{final.name}.building-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    build_dataset(spec, staging, workers=workers, on_map_done=on_map_done)
    if final.exists() and (force or not is_complete(final)):
        shutil.rmtree(final)
    rename_into_place(staging, final, is_complete)  # another process's, if first: theirs
    return final


def ensure_sample(root: str | Path | None = None) -> Path:
    """The bundled sample (a few maps, a few dozen episodes per split), built on first use."""
    return ensure_dataset("sample", root)
