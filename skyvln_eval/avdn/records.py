"""Typed AVDN records and episodes.

An :class:`AvdnRecord` is one element of an ``*_data.json`` list (one dialog round, a
"sub-trajectory"). An :class:`Episode` is what an agent is evaluated on: one record in
ANDH mode, a whole trajectory (all rounds) in ANDH-Full mode. Records keep the JSON they
were parsed from (``source``), so files written from them carry the record's values exactly (keys in
their order, numbers as parsed), not its text.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import DEFAULT_MAX_ACTION_LEN, EpisodeMode
from skyvln_eval.avdn.imagery import MapGeoref

LatLng = tuple[float, float]
Speaker = Literal["commander", "follower"]

#: Keys of a record, in the order the AVDN release writes them.
RECORD_KEYS: tuple[str, ...] = (
    "map_name",
    "route_index",
    "last_round_idx",
    "instructions",
    "pre_dialogs",
    "gps_botm_left",
    "gps_top_right",
    "lng_ratio",
    "lat_ratio",
    "angle",
    "destination",
    "gt_path_corners",
    "attention_list",
)
OPTIONAL_KEYS: frozenset[str] = frozenset({"last_round_idx", "destination"})
REQUIRED_KEYS: tuple[str, ...] = tuple(k for k in RECORD_KEYS if k not in OPTIONAL_KEYS)


def episode_id_of(map_name: str, route_index: str) -> str:
    """The unique episode id of a record: ``f"{map_name}__{route_index}"``."""
    return f"{map_name}__{route_index}"


def trajectory_of(episode_id: str) -> str:
    """The trajectory an episode id of :func:`episode_id_of` (``<map>__<trajectory>_<round>``)
    belongs to: ``<map>__<trajectory>``; any other id is a trajectory of its own."""
    map_name, sep, route = episode_id.rpartition("__")
    trajectory, underscore, round_index = route.rpartition("_")
    if not sep or not underscore or not trajectory or not round_index.isdigit():
        return episode_id
    return f"{map_name}__{trajectory}"


@dataclass(frozen=True)
class AttentionCircle:
    """A human attention circle: centre ``(lat, lng)`` and radius in resized-map pixels."""

    centre: LatLng
    radius_px: float


@dataclass(frozen=True)
class DialogTurn:
    """One utterance: the commander's instruction (``[INS]``) or the follower's question."""

    round_index: int
    speaker: Speaker
    text: str


_TAG = re.compile(r"\[(INS|QUE)\]")


def parse_utterances(text: str, round_index: int) -> list[DialogTurn]:
    """Split ``"[QUE] ... [INS] ..."`` into turns; untagged text counts as an instruction."""
    turns: list[DialogTurn] = []
    pieces = _TAG.split(text)
    lead = pieces[0].strip()
    if lead:
        turns.append(DialogTurn(round_index, "commander", lead))
    for tag, body in zip(pieces[1::2], pieces[2::2], strict=True):
        speaker: Speaker = "follower" if tag == "QUE" else "commander"
        turns.append(DialogTurn(round_index, speaker, body.strip()))
    return turns


def _arrays_equal(a: NDArray[Any] | None, b: NDArray[Any] | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and bool(np.array_equal(a, b))


@dataclass(frozen=True, eq=False)
class AvdnRecord:
    """One AVDN annotation record (one dialog round), validated and typed.

    Corner arrays are ``[lat, lng]`` degrees, read-only: ``gt_path_corners`` is
    ``(N, 4, 2)`` with the start view first; ``destination`` is ``(4, 2)`` or ``None``.
    ``extra`` holds keys the AVDN format does not define, kept so nothing is lost.
    """

    map_name: str
    route_index: str
    instructions: str
    pre_dialogs: tuple[str, ...]
    gps_botm_left: LatLng
    gps_top_right: LatLng
    lng_ratio: float
    lat_ratio: float
    angle: float
    gt_path_corners: NDArray[np.float64]
    attention_list: tuple[AttentionCircle, ...]
    last_round_idx: int | None = None
    destination: NDArray[np.float64] | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    source: Mapping[str, Any] | None = field(default=None, repr=False)

    @property
    def episode_id(self) -> str:
        return episode_id_of(self.map_name, self.route_index)

    @property
    def trajectory_index(self) -> str:
        """The trajectory part of ``route_index`` (``"3"`` in ``"3_2"``)."""
        return self.route_index.split("_", 1)[0]

    @property
    def round_index(self) -> int:
        """The dialog round of this record, counted from 1."""
        return int(self.route_index.split("_", 1)[1])

    @property
    def start_heading_deg(self) -> int:
        """The start heading as the official loader uses it: ``round(angle) % 360``."""
        return round(self.angle) % 360

    @property
    def georef(self) -> MapGeoref:
        return MapGeoref(self.gps_botm_left, self.gps_top_right, self.lng_ratio, self.lat_ratio)

    @property
    def has_ground_truth(self) -> bool:
        """False when only the start view is given (the real AVDN test_unseen release)."""
        return len(self.gt_path_corners) >= 2

    def dialog(self) -> list[DialogTurn]:
        """Earlier rounds' utterances, then this round's, as turns."""
        turns: list[DialogTurn] = []
        for k, text in enumerate(self.pre_dialogs, start=1):
            turns.extend(parse_utterances(text, k))
        turns.extend(parse_utterances(self.instructions, self.round_index))
        return turns

    def to_json_dict(self) -> dict[str, Any]:
        """The record as AVDN JSON: the verbatim source when known, else rebuilt."""
        if self.source is not None:
            return dict(self.source)
        out: dict[str, Any] = {
            "map_name": self.map_name,
            "route_index": self.route_index,
            "last_round_idx": self.last_round_idx,
            "instructions": self.instructions,
            "pre_dialogs": list(self.pre_dialogs),
            "gps_botm_left": list(self.gps_botm_left),
            "gps_top_right": list(self.gps_top_right),
            "lng_ratio": self.lng_ratio,
            "lat_ratio": self.lat_ratio,
            "angle": self.angle,
            "destination": None if self.destination is None else self.destination.tolist(),
            "gt_path_corners": self.gt_path_corners.tolist(),
            "attention_list": [[list(a.centre), a.radius_px] for a in self.attention_list],
        }
        for key in OPTIONAL_KEYS:
            if out[key] is None:
                del out[key]
        out.update(self.extra)
        return out

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AvdnRecord):
            return NotImplemented
        return (
            self.map_name == other.map_name
            and self.route_index == other.route_index
            and self.instructions == other.instructions
            and self.pre_dialogs == other.pre_dialogs
            and self.gps_botm_left == other.gps_botm_left
            and self.gps_top_right == other.gps_top_right
            and self.lng_ratio == other.lng_ratio
            and self.lat_ratio == other.lat_ratio
            and self.angle == other.angle
            and _arrays_equal(self.gt_path_corners, other.gt_path_corners)
            and self.attention_list == other.attention_list
            and self.last_round_idx == other.last_round_idx
            and _arrays_equal(self.destination, other.destination)
            and dict(self.extra) == dict(other.extra)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class Episode:
    """What an agent is evaluated on.

    ANDH: one record; the ground truth is its ``gt_path_corners``. ANDH-Full: all rounds
    of a trajectory, sorted by round; the agent starts at round 1's start view and the
    ground truth is every round's views in order, ending at the final round's last view
    (a round that starts at the view the previous one ended at adds that view once: a
    repeated reference point would weigh twice in nDTW and CLS). ``episode_id`` is the
    first record's id in both modes, as in the official code.
    """

    split: str
    mode: EpisodeMode
    records: tuple[AvdnRecord, ...]

    @property
    def first(self) -> AvdnRecord:
        return self.records[0]

    @property
    def episode_id(self) -> str:
        return self.first.episode_id

    @property
    def map_name(self) -> str:
        return self.first.map_name

    @property
    def trajectory_index(self) -> str:
        return self.first.trajectory_index

    @property
    def georef(self) -> MapGeoref:
        return self.first.georef

    @property
    def start_view(self) -> NDArray[np.float64]:
        return self.first.gt_path_corners[0]

    @property
    def start_heading_deg(self) -> int:
        return self.first.start_heading_deg

    @property
    def gt_path_corners(self) -> NDArray[np.float64]:
        if len(self.records) == 1:
            return self.first.gt_path_corners
        return np.concatenate([views for views, _ in self._rounds()])

    def round_starts(self) -> dict[int, int]:
        """By round index, the index in :attr:`gt_path_corners` of the view the round
        starts from (a view two rounds share: the previous round's last)."""
        return {
            r.round_index: start for r, (_, start) in zip(self.records, self._rounds(), strict=True)
        }

    def _rounds(self) -> list[tuple[NDArray[np.float64], int]]:
        """Each round's views in the ground truth (a shared first view left out) and the
        index its start view has there."""
        out: list[tuple[NDArray[np.float64], int]] = []
        added, last = 0, None
        for record in self.records:
            views = record.gt_path_corners  # every record has at least its start view
            shared = last is not None and np.array_equal(views[0], last)
            out.append((views[1:] if shared else views, added - 1 if shared else added))
            added += len(views) - int(shared)
            last = views[-1]
        return out

    @property
    def gt_end_view(self) -> NDArray[np.float64]:
        return self.records[-1].gt_path_corners[-1]

    def view_budget(self, max_action_len: int = DEFAULT_MAX_ACTION_LEN) -> int:
        """The views the episode may have, the start included: AVDN's ``max_action_len``
        for each dialog round flown (ANDH: one; ANDH-Full: every round of the trajectory).

        AVDN's code gives ANDH-Full one round's budget, in which a long trajectory's own
        ground-truth route does not fit (11 of the sample's 53 have more than 10 views:
        replaying the ground truth scored SR 88.7%, not 100); a round's budget per round
        holds every route (each round's fits in one)."""
        return max_action_len * self.rounds_flown

    @property
    def rounds_flown(self) -> int:
        """The dialog rounds whose routes the episode flies: one (ANDH), or every round of
        the trajectory (ANDH-Full)."""
        return len(self.records) if self.mode == "andh-full" else 1

    @property
    def has_ground_truth(self) -> bool:
        return all(r.has_ground_truth for r in self.records)

    @property
    def destination(self) -> NDArray[np.float64] | None:
        return self.records[-1].destination

    def dialog(self) -> list[DialogTurn]:
        """The dialog the agent receives at the start: ANDH, the earlier rounds and this
        round's; ANDH-Full, every round's (AVDN's ANDH-Full gives the whole dialog at the
        start, the later rounds' words included)."""
        if self.mode == "andh":
            return self.first.dialog()
        turns: list[DialogTurn] = []
        for record in self.records:
            turns.extend(parse_utterances(record.instructions, record.round_index))
        return turns

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Episode):
            return NotImplemented
        return (
            self.split == other.split
            and self.mode == other.mode
            and len(self.records) == len(other.records)
            and all(a == b for a, b in zip(self.records, other.records, strict=True))
        )

    __hash__ = None  # type: ignore[assignment]
