"""``DIALOGS.json``: the facts each synthetic dialog says and the frames it was written with.

The builder keeps, per trajectory, the facts of every round (:mod:`.facts`), the seed of
its wording stream and the ids of the frames each round used. Rendering the facts again
with the split's own families and that seed gives the annotation text back byte for
byte; rendering them with other families gives the same routes in other words
(:func:`rephrase_records`), which is how phrasing is studied apart from routes.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

from skyvln_eval.avdn.records import AvdnRecord
from skyvln_eval.errors import DataError, FormatVersionError
from skyvln_eval.worlds.sample.dialogs import DIALOG_VERSION, render_trajectory
from skyvln_eval.worlds.sample.facts import RoundFacts
from skyvln_eval.worlds.sample.phrasebook import SPLIT_FAMILIES, all_frames

DIALOGS_FILE: Final = "DIALOGS.json"
DIALOGS_FORMAT: Final = "skyvln-eval/synthetic-dialogs"


@dataclass(frozen=True)
class TrajectoryDialog:
    """One trajectory's dialog: its rounds' facts, wording seed and frames used."""

    map_name: str
    trajectory: str
    wording_seed: int
    rounds: tuple[RoundFacts, ...]
    frames: tuple[tuple[str, ...], ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "map_name": self.map_name,
            "trajectory": self.trajectory,
            "wording_seed": self.wording_seed,
            "rounds": [r.to_dict() for r in self.rounds],
            "frames": [list(f) for f in self.frames],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrajectoryDialog:
        return cls(
            data["map_name"],
            data["trajectory"],
            int(data["wording_seed"]),
            tuple(RoundFacts.from_dict(r) for r in data["rounds"]),
            tuple(tuple(f) for f in data["frames"]),
        )


@dataclass(frozen=True)
class DialogSources:
    """The whole ``DIALOGS.json`` of a synthetic dataset."""

    split_families: dict[str, tuple[str, ...]]
    frame_families: dict[str, str]
    trajectories: dict[str, tuple[TrajectoryDialog, ...]]

    def frames_used(self, split: str) -> set[str]:
        return {f for t in self.trajectories[split] for frames in t.frames for f in frames}


def dialogs_document(trajectories: dict[str, list[TrajectoryDialog]]) -> dict[str, Any]:
    """The JSON of ``DIALOGS.json``: the split table, every frame, every trajectory."""
    return {
        "format": DIALOGS_FORMAT,
        "version": DIALOG_VERSION,
        "split_families": {split: list(f) for split, f in SPLIT_FAMILIES.items()},
        "frames": {
            f.frame_id: {"family": f.family, "slot": f.slot, "template": f.template}
            for f in all_frames()
        },
        "trajectories": {s: [t.to_dict() for t in ts] for s, ts in trajectories.items()},
    }


def load_dialogs(data_dir: str | Path) -> DialogSources:
    """Read ``DIALOGS.json`` of a synthetic dataset folder (only synthetic data has one)."""
    path = Path(data_dir) / DIALOGS_FILE
    if not path.is_file():
        raise DataError(f"{path}: no {DIALOGS_FILE}; only the synthetic datasets have one")
    data = json.loads(path.read_text(encoding="utf-8"))
    if data.get("format") != DIALOGS_FORMAT or data.get("version") != DIALOG_VERSION:
        raise FormatVersionError(
            str(path),
            (data.get("format"), data.get("version")),
            (DIALOGS_FORMAT, DIALOG_VERSION),
            "Regenerate the dataset with this version (delete it from the cache).",
        )
    return DialogSources(
        {s: tuple(f) for s, f in data["split_families"].items()},
        {frame_id: f["family"] for frame_id, f in data["frames"].items()},
        {
            s: tuple(TrajectoryDialog.from_dict(t) for t in ts)
            for s, ts in data["trajectories"].items()
        },
    )


def rephrase_records(
    records: Sequence[AvdnRecord], sources: DialogSources, split: str, families: Sequence[str]
) -> list[AvdnRecord]:
    """``records`` of ``split`` with every dialog written anew by ``families``: the same
    routes, facts and ground truth; only the words (and earlier rounds' words) change."""
    texts: dict[tuple[str, str], list[str]] = {}
    for t in sources.trajectories[split]:
        utterances = render_trajectory(t.rounds, families, t.wording_seed)
        texts[(t.map_name, t.trajectory)] = [u.text for u in utterances]
    out = []
    for record in records:
        rounds = texts[(record.map_name, record.trajectory_index)]
        k = record.round_index - 1
        out.append(replace(record, instructions=rounds[k], pre_dialogs=tuple(rounds[:k])))
    return out
