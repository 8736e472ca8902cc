"""Score predictions made elsewhere: the official agent's ``.npy`` output and a JSON format.

**Official format.** The official AVDN code saves ``np.save(path, results)`` where
``results`` maps episode id (``"<map_name>__<route_index>"``) to a dict (a
``defaultdict(list)``) whose ``path_corners`` is a list of ``(corners (4, 2) array,
heading)`` tuples, start view first; it also holds ``actions``, ``progress``,
``gt_path_corners`` and more, which are ignored (its ``gt_path_corners`` carry the
loader's random noise and, on test_unseen, a made-up second view, so the ground truth
always comes from the dataset). Such a file is a pickle: :func:`read_official_npy`
unpickles it with an allow-list of plain containers, numbers, strings and numpy
arrays / scalars, and refuses anything else (a pickle can run arbitrary code).

**JSON format** (``.json``), for any agent::

    {"format": "skyvln-eval.predictions", "version": 1,
     "episodes": {"<episode_id>": {"path_corners": [[[lat, lng] x 4], ...],
                                   "status": "ok"}}}

``path_corners`` are the visited views, start view first; ``status`` is optional
(``"ok"`` by default; ``"degraded"``; ``"error"`` for an episode that failed, which may
have no view and never succeeds, with an optional ``"error"`` text saying what went
wrong). Nothing in the file says what the agent's model calls cost: its results' LLM
counts, cost and time are unknown ("n/a"), not 0.

:func:`results_from_predictions` joins predictions with the ground truth of a split and
fails on missing or unknown episodes, naming them.
"""

from __future__ import annotations

import json
import pickle
from collections import OrderedDict, defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import EpisodeMode
from skyvln_eval.avdn.loader import RepeatedKeys, object_keeping_repeats
from skyvln_eval.avdn.records import Episode
from skyvln_eval.avdn.validation import view_problems
from skyvln_eval.errors import (
    DataError,
    FormatVersionError,
    ResultRecordError,
    UnsafePickleError,
    ValidationIssue,
)
from skyvln_eval.fileio import atomic_write_json
from skyvln_eval.metrics.aggregate import check_complete
from skyvln_eval.metrics.records import RESULT_STATUSES, EpisodeResult, ResultStatus, as_views
from skyvln_eval.metrics.results_io import START_VIEW_TOLERANCE_DEG

PREDICTIONS_FORMAT = "skyvln-eval.predictions"
PREDICTIONS_VERSION = 1


@dataclass(frozen=True)
class Prediction:
    """Visited views ``(K, 4, 2)`` of one episode (start first) and its status."""

    episode_id: str
    path_corners: NDArray[np.float64]
    status: ResultStatus = "ok"
    error: str | None = None
    #: The file it was read from ('' when made in Python), for messages.
    source: str = ""


def _allowed_globals() -> dict[tuple[str, str], Any]:
    import importlib

    # numpy 2 names its internals numpy._core, numpy 1 numpy.core.
    base = "numpy._core" if hasattr(np, "_core") else "numpy.core"
    core = importlib.import_module(f"{base}.multiarray")
    numeric = importlib.import_module(f"{base}.numeric")
    allowed: dict[tuple[str, str], Any] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        ("collections", "defaultdict"): defaultdict,
        ("collections", "OrderedDict"): OrderedDict,
    }
    # numpy 1 pickles name numpy.core, numpy 2 numpy._core: accept both spellings.
    for prefix in ("numpy.core", "numpy._core"):
        allowed[(f"{prefix}.multiarray", "_reconstruct")] = core._reconstruct
        allowed[(f"{prefix}.multiarray", "scalar")] = core.scalar
        allowed[(f"{prefix}.numeric", "_frombuffer")] = numeric._frombuffer
    for name in (
        "list",
        "dict",
        "tuple",
        "set",
        "frozenset",
        "int",
        "float",
        "complex",
        "str",
        "bytes",
        "bytearray",
        "bool",
    ):
        allowed[("builtins", name)] = getattr(__import__("builtins"), name)
    return allowed


class _PlainDataUnpickler(pickle.Unpickler):
    """An unpickler that resolves only allow-listed globals (plain data and numpy arrays)."""

    def __init__(self, file: Any, source: str) -> None:
        super().__init__(file)
        self._source = source
        self._allowed = _allowed_globals()

    def find_class(self, module: str, name: str) -> Any:
        try:
            return self._allowed[(module, name)]
        except KeyError:
            raise UnsafePickleError(self._source, f"{module}.{name}") from None


def read_official_npy(path: str | Path) -> dict[str, Prediction]:
    """Read the official agent's ``np.save``-d results dict safely (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: predictions file not found")
    with path.open("rb") as handle:
        try:
            version = np.lib.format.read_magic(handle)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
            else:
                shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
        except ValueError as exc:
            raise DataError(f"{path}: not a .npy file ({exc})") from None
        if dtype != np.dtype(object) or shape != ():
            raise DataError(
                f"{path}: expected a pickled dict (object array of shape ()), "
                f"got dtype {dtype}, shape {shape}"
            )
        try:
            array = _PlainDataUnpickler(handle, str(path)).load()
        except UnsafePickleError:
            raise
        except Exception as exc:  # a truncated or corrupt pickle raises many types
            raise DataError(f"{path}: unreadable pickle ({type(exc).__name__}: {exc})") from None
    data = array.item() if isinstance(array, np.ndarray) else array
    if not isinstance(data, Mapping):
        raise DataError(
            f"{path}: expected a dict of episode id -> result, got {type(data).__name__}"
        )
    return {
        str(k): _prediction(str(k), v, str(path), row) for row, (k, v) in enumerate(data.items())
    }


def _views_of(path_corners: Any) -> list[Any]:
    """Official entries are ``(corners, heading)`` tuples; JSON entries are bare corners."""
    views = []
    for entry in path_corners:
        if (isinstance(entry, tuple) and len(entry) == 2) or (
            isinstance(entry, list) and len(entry) == 2 and np.shape(entry[0]) == (4, 2)
        ):  # official: (corners, heading)
            views.append(entry[0])
        else:
            views.append(entry)
    return views


def _prediction(episode_id: str, entry: Any, file: str, row: int) -> Prediction:
    def bad(field: str, message: str) -> ResultRecordError:
        return ResultRecordError(ValidationIssue(file, message, row, episode_id, field))

    if not isinstance(entry, Mapping) or "path_corners" not in entry:
        raise bad("path_corners", "each episode needs a 'path_corners' list")
    status = entry.get("status", "ok")
    if status not in RESULT_STATUSES:
        raise bad("status", f"must be one of {RESULT_STATUSES}, got {status!r}")
    error = entry.get("error")
    if error is not None and not isinstance(error, str):
        raise bad("error", f"must be a string saying what went wrong, got {error!r}")
    if error and status != "error":
        raise bad("error", f"an error text needs status 'error', got status {status!r}")
    if status == "error" and not error:
        error = f"status 'error' in {file}"  # the file said it failed, not why
    try:
        views = as_views(_views_of(entry["path_corners"]), "path_corners", episode_id, 0)
    except ResultRecordError as exc:
        raise bad(exc.issue.field or "path_corners", exc.issue.message) from None
    if len(views) == 0 and status != "error":  # flown from its start view at least
        raise bad("path_corners", f"a {status!r} episode's path includes at least its start view")
    return Prediction(episode_id, views, status, error, source=file)


def _check_views(
    prediction: Prediction, bounds: tuple[tuple[float, float], tuple[float, float]] | None
) -> None:
    """Refuse a path view the annotation checks would refuse in the ground truth: one
    corner moved 0.001 degrees (no square) scored SR 1, four equal corners were a view,
    and a view 1 degree off the map scored NE 111,300 m. ``bounds`` (the map's
    gps_botm_left, gps_top_right) are known when the ground truth is the split's episodes."""
    problems = view_problems(prediction.path_corners, bounds)
    if problems:
        k, problem = problems[0]
        issue = ValidationIssue(
            prediction.source or "<predictions>",
            problem,
            None,
            prediction.episode_id,
            f"path_corners[{k}]",
        )
        raise ResultRecordError(issue)


def read_predictions_json(path: str | Path) -> dict[str, Prediction]:
    """Read the documented JSON predictions format (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: predictions file not found")
    try:
        data = json.loads(path.read_bytes(), object_pairs_hook=object_keeping_repeats)
    except ValueError as exc:  # not JSON, not UTF-8, an integer of thousands of digits
        raise DataError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != PREDICTIONS_FORMAT:
        raise DataError(f'{path}: not a predictions file (needs "format": "{PREDICTIONS_FORMAT}")')
    if data.get("version") != PREDICTIONS_VERSION:
        raise FormatVersionError(
            str(path),
            data.get("version"),
            PREDICTIONS_VERSION,
            "Write it in version 1 of the format (see skyvln_eval.metrics.predictions).",
        )
    episodes = data.get("episodes")
    if not isinstance(episodes, dict):
        raise DataError(f"{path}: 'episodes' must be an object of episode id -> prediction")
    # JSON keeps the last of a repeated key silently: which one is meant is not known.
    if isinstance(data, RepeatedKeys):
        raise DataError(f"{path}: key(s) given more than once: {', '.join(data.repeated)}")
    if isinstance(episodes, RepeatedKeys):
        raise DataError(
            f"{path}: 'episodes' lists episode(s) more than once: {', '.join(episodes.repeated)}"
        )
    for episode_id, entry in episodes.items():
        if isinstance(entry, RepeatedKeys):
            raise DataError(
                f"{path}: episode {episode_id}: key(s) given more than once: "
                f"{', '.join(entry.repeated)}"
            )
    return {k: _prediction(k, v, str(path), row) for row, (k, v) in enumerate(episodes.items())}


def write_predictions_json(path: str | Path, predictions: Mapping[str, Prediction]) -> None:
    """Write predictions in the JSON format (atomically)."""
    episodes = {
        eid: {"path_corners": p.path_corners.tolist(), "status": p.status}
        | ({"error": p.error} if p.error else {})
        for eid, p in predictions.items()
    }
    atomic_write_json(
        path, {"format": PREDICTIONS_FORMAT, "version": PREDICTIONS_VERSION, "episodes": episodes}
    )


def read_predictions(path: str | Path) -> dict[str, Prediction]:
    """Official ``.npy`` or JSON predictions, chosen by suffix."""
    suffix = Path(path).suffix
    if suffix == ".npy":
        return read_official_npy(path)
    if suffix == ".json":
        return read_predictions_json(path)
    raise DataError(f"{path}: unknown predictions format; expected .npy (official) or .json")


def ground_truth_episodes(
    data_dir: str | Path, split: str, mode: EpisodeMode = "andh"
) -> list[Episode]:
    """The episodes of a dataset split, refusing splits whose ground truth is withheld.

    Raises :class:`~skyvln_eval.errors.NoGroundTruthError` for the real AVDN test_unseen
    (start views only); the synthetic sample's test_unseen keeps its ground truth.
    """
    from skyvln_eval.avdn.loader import load_split

    loaded = load_split(data_dir, split, check_map_images=False)
    loaded.require_ground_truth()
    return loaded.episodes(mode)


def results_from_predictions(
    predictions: Mapping[str, Prediction],
    ground_truth: Mapping[str, NDArray[np.float64]] | Sequence[Episode],
    system: str,
    split: str,
    mode: EpisodeMode = "andh",
    allow_missing: bool = False,
) -> list[EpisodeResult]:
    """Join predictions with ground truth into results, in ground-truth order.

    ``ground_truth`` is either the split's episodes (their ``gt_path_corners``) or a
    mapping of episode id to GT views. Every GT episode must have a prediction (unless
    ``allow_missing``: then only the predicted ones are joined) and every prediction a GT
    episode; otherwise :class:`~skyvln_eval.errors.IncompleteRunError` names them. A
    path must begin with its episode's start view (AVDN's P_0), else
    :class:`~skyvln_eval.errors.DataError`: without it the path would be shorter and its
    SPL higher.
    """
    bounds: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {}
    rounds: dict[str, int] = {}
    if isinstance(ground_truth, Mapping):
        gt = dict(ground_truth)
    else:
        gt = {ep.episode_id: ep.gt_path_corners for ep in ground_truth}
        bounds = {
            ep.episode_id: (ep.georef.gps_botm_left, ep.georef.gps_top_right) for ep in ground_truth
        }
        rounds = {ep.episode_id: ep.rounds_flown for ep in ground_truth}
    sources = sorted({p.source for p in predictions.values() if p.source})
    what = f"predictions of {system!r} on {split}" + (f" ({', '.join(sources)})" if sources else "")
    if allow_missing:
        gt = {eid: views for eid, views in gt.items() if eid in predictions}
    check_complete(predictions, gt, what)
    for eid, views in gt.items():
        path = predictions[eid].path_corners
        if len(path) and not np.allclose(
            path[0], views[0], rtol=0.0, atol=START_VIEW_TOLERANCE_DEG
        ):
            first, start = np.asarray(path[0]).tolist(), np.asarray(views[0]).tolist()
            raise DataError(
                f"{what}, episode {eid}: the path does not begin with the episode's start view "
                f"(first view {first}, start {start}); a path lists every view from the start "
                "on, as the official agent's path_corners do"
            )
        _check_views(predictions[eid], bounds.get(eid))
    return [
        EpisodeResult(
            episode_id=eid,
            split=split,
            mode=mode,
            system=system,
            status=predictions[eid].status,
            error=predictions[eid].error,
            visited_views=predictions[eid].path_corners,
            gt_path_corners=views,
            # The file says where the agent went, not what its model calls cost.
            extra={"llm_use_recorded": False}
            | ({"rounds_flown": rounds[eid]} if eid in rounds else {}),
        )
        for eid, views in gt.items()
    ]
