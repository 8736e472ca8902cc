"""Shared fixtures: small hand-made AVDN datasets and the bundled synthetic sample."""

from __future__ import annotations

import ast
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from skyvln_eval.avdn import view_from_pose

REPO = Path(__file__).resolve().parent.parent
# Nothing in the tests may come from the Hugging Face hub (the tiny GroundingDINO is built in
# the test). huggingface_hub reads this once, when first imported, so it is set here, before
# any test module imports datasets or transformers.
os.environ["HF_HUB_OFFLINE"] = "1"
FIXTURES = REPO / "tests" / "fixtures"


def _shared_fixtures() -> Path:
    """The project's shared fixtures: $SKYVLN_SHARED_DIR, else ../shared beside the checkout,
    else /work/shared (where CI clones elsewhere on the same machine)."""
    candidates = [Path(p) for p in (os.environ.get("SKYVLN_SHARED_DIR"),) if p]
    candidates += [REPO.parent / "shared", Path("/work/shared")]
    for candidate in candidates:
        if (candidate / "fixtures").is_dir():
            return candidate / "fixtures"
    return candidates[0] / "fixtures"


SHARED_FIXTURES = _shared_fixtures()

BOTM_LEFT = (30.0, 40.0)
TOP_RIGHT = (30.01, 40.01)  # about 1.1 km square in flat degrees


def modules_loaded_by(module: str, prefixes: tuple[str, ...]) -> list[str]:
    """Modules starting with one of ``prefixes`` that importing ``module`` loads, in a
    fresh interpreter (so nothing imported by the tests themselves counts)."""
    import subprocess
    import sys

    code = f"import sys, {module}\nprint([m for m in sys.modules if m.startswith({prefixes!r})])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    return list(ast.literal_eval(out.stdout.strip()))


def make_record(
    map_name: str = "1913",
    route_index: str = "0_1",
    n_views: int = 3,
    heading: float = 30.0,
    **overrides: Any,
) -> dict[str, Any]:
    """A valid AVDN record on a 0.01 x 0.01 degree map, moving forward along ``heading``."""
    centre = np.array([30.005, 40.005])
    views = []
    for k in range(n_views):
        offset = np.array([np.cos(np.radians(heading)), np.sin(np.radians(heading))]) * 0.0004 * k
        views.append(view_from_pose(centre + offset, heading, 100.0).tolist())
    record: dict[str, Any] = {
        "map_name": map_name,
        "route_index": route_index,
        "last_round_idx": int(route_index.split("_")[-1]),
        "instructions": "[INS] go north and stop at the red building.",
        "pre_dialogs": [],
        "gps_botm_left": list(BOTM_LEFT),
        "gps_top_right": list(TOP_RIGHT),
        "lng_ratio": 1e-5,
        "lat_ratio": 1e-5,
        "angle": heading,
        "destination": [list(corner) for corner in views[-1]],
        "gt_path_corners": views,
        "attention_list": [[[30.005, 40.005], 20]],
    }
    record.update(overrides)
    return record


def write_dataset(
    root: Path, splits: dict[str, list[Any]], maps: tuple[str, ...] = ("1913",), image_px: int = 100
) -> Path:
    """Write annotation files (any JSON, valid or not) and small map images.

    The images are ``image_px`` square; :func:`make_record`'s bounds and ratios describe a
    1000 px one, which ``validate`` (it compares the two) needs."""
    (root / "annotations").mkdir(parents=True, exist_ok=True)
    (root / "train_images").mkdir(parents=True, exist_ok=True)
    for split, data in splits.items():
        (root / "annotations" / f"{split}_data.json").write_text(json.dumps(data))
    image = np.full((image_px, image_px, 3), 128, np.uint8)
    for name in maps:
        cv2.imwrite(str(root / "train_images" / f"{name}.tif"), image)
    return root


@pytest.fixture
def dataset_factory(tmp_path: Path) -> Callable[..., Path]:
    counter = iter(range(1000))

    def factory(
        splits: dict[str, list[Any]], maps: tuple[str, ...] = ("1913",), image_px: int = 100
    ) -> Path:
        return write_dataset(tmp_path / f"ds{next(counter)}", splits, maps, image_px)

    return factory


@pytest.fixture(scope="session", autouse=True)
def _hermetic_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Everything the toolkit caches (datasets, episode logs, compiled solvers) goes to a
    temporary folder, unless SKYVLN_EVAL_CACHE names one to reuse between test runs.

    The test processes of one ``pytest -n`` run share that folder (the base temporary
    folder's parent is theirs in common): the sample and the compiled solvers are built
    once, not once per process. Every cache entry is written under a temporary name and
    renamed, so processes that build the same entry at once keep one of them."""
    if "SKYVLN_EVAL_CACHE" in os.environ:
        return
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent / "skyvln-cache"
        shared.mkdir(exist_ok=True)
        os.environ["SKYVLN_EVAL_CACHE"] = str(shared)
    else:
        os.environ["SKYVLN_EVAL_CACHE"] = str(tmp_path_factory.mktemp("skyvln-cache"))


@pytest.fixture(scope="session")
def sample_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled synthetic sample, built once per session (or reused from the cache).

    Set SKYVLN_EVAL_CACHE to reuse a cache between runs; otherwise it is built into a
    temporary folder.
    """
    from skyvln_eval.worlds.sample import ensure_sample

    root = os.environ.get("SKYVLN_EVAL_CACHE") or tmp_path_factory.mktemp("cache")
    return ensure_sample(root)


@dataclass(frozen=True)
class CliOutcome:
    """What the ``skyvln-eval`` console script did: exit code, stdout, stderr."""

    code: int
    out: str
    err: str


@pytest.fixture
def cli(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Callable[..., CliOutcome]:
    """Run the console script's entry point in this process, as a user's shell would
    (errors printed as messages and exit codes, not exceptions)."""
    from skyvln_eval.cli import main

    def invoke(*args: str) -> CliOutcome:
        monkeypatch.setattr(sys, "argv", ["skyvln-eval", *args])
        capsys.readouterr()
        try:
            main()
            code = 0
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else int(stop.code is not None)
        captured = capsys.readouterr()
        return CliOutcome(code, captured.out, captured.err)

    return invoke
