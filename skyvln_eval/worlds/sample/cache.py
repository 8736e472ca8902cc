"""Where the bundled synthetic dataset lives, and building it on first use.

The sample is generated, not shipped: on first use it is built into the cache
(``$SKYVLN_EVAL_CACHE``, else ``$XDG_CACHE_HOME/skyvln-eval``, else
``~/.cache/skyvln-eval``) under a name that includes the generator, flight and dialog
versions and a hash of the spec, in a temporary folder renamed into place when complete.
:func:`write_dataset` builds one into a folder of the caller's choice instead
(``skyvln-eval sample --out DIR`` writes DIR itself).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from skyvln_eval.errors import ConfigError
from skyvln_eval.fileio import rename_into_place
from skyvln_eval.paths import cache_root
from skyvln_eval.worlds.city.generate import GENERATOR_VERSION
from skyvln_eval.worlds.sample.build import DATASET_INFO, SPECS, DatasetSpec, build_dataset
from skyvln_eval.worlds.sample.dialogs import DIALOG_VERSION
from skyvln_eval.worlds.sample.pilot import FLIGHT_VERSION


def dataset_dir_name(spec: DatasetSpec) -> str:
    digest = hashlib.sha256(json.dumps(_spec_json(spec), sort_keys=True).encode()).hexdigest()[:10]
    return f"{spec.name}-g{GENERATOR_VERSION}f{FLIGHT_VERSION}d{DIALOG_VERSION}-{digest}"


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
    # The folder's name is the spec's, so a complete one there is this dataset.
    _build_in_place(spec, final, workers, on_map_done, force, done=is_complete)
    return final


def write_dataset(
    spec: DatasetSpec | str,
    out_dir: str | Path,
    workers: int = 1,
    force: bool = False,
    on_map_done: Callable[[str], None] | None = None,
) -> Path:
    """A synthetic dataset in ``out_dir`` itself (``skyvln-eval sample --out``), built
    unless that folder holds it already; ``force`` rebuilds it, or replaces another
    synthetic dataset there. A folder holding anything else is refused, never emptied."""
    spec = SPECS[spec] if isinstance(spec, str) else spec
    final = Path(out_dir)
    if holds_dataset(spec, final) and not force:
        return final
    if is_complete(final) and not force:
        raise ConfigError(
            f"--out {final}: holds another synthetic dataset (of another size or generator "
            "version); --force replaces it, or choose another folder"
        )
    if final.is_file() or (final.is_dir() and not is_complete(final) and any(final.iterdir())):
        raise ConfigError(
            f"--out {final}: {'a file' if final.is_file() else 'a folder that is not empty'} "
            "and no synthetic dataset; give a new or empty folder"
        )
    _build_in_place(spec, final, workers, on_map_done, force, done=lambda p: holds_dataset(spec, p))
    return final


def holds_dataset(spec: DatasetSpec, path: Path) -> bool:
    """Whether ``path`` is the complete dataset of ``spec`` by this generator version."""
    try:
        info = json.loads((path / DATASET_INFO).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (
        isinstance(info, dict)
        and info.get("generator_version") == GENERATOR_VERSION
        and info.get("dialog_version") == DIALOG_VERSION
        and info.get("flight_version") == FLIGHT_VERSION
        and info.get("spec") == json.loads(json.dumps(_spec_json(spec)))
    )


def _spec_json(spec: DatasetSpec) -> dict[str, object]:
    return {**asdict(spec), "records": dict(spec.records)}


def _build_in_place(
    spec: DatasetSpec,
    final: Path,
    workers: int,
    on_map_done: Callable[[str], None] | None,
    force: bool,
    done: Callable[[Path], bool],
) -> None:
    """Build into a hidden sibling of ``final`` and rename it into place when complete, so
    that an interrupted build never leaves a half dataset where a reader looks for one.
    What is at ``final`` then (an empty folder, a dataset ``done`` does not accept, any
    with ``force``) is removed first; one another process finished meanwhile is kept."""
    final.parent.mkdir(parents=True, exist_ok=True)
    staging = final.parent / f".{final.name}.building-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    build_dataset(spec, staging, workers=workers, on_map_done=on_map_done)
    if final.exists() and (force or not done(final)):
        shutil.rmtree(final)
    rename_into_place(staging, final, done)  # another process's, if first: theirs


def ensure_sample(root: str | Path | None = None) -> Path:
    """The bundled sample (a few maps, a few dozen episodes per split), built on first use."""
    return ensure_dataset("sample", root)
