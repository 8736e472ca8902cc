"""What the synthetic commander says in each round, before it is put into words.

The content of a dialog (headings, turns, landmarks passed, where to stop, the follower's
question) is drawn here from the trajectory's random stream; the wording is chosen later
and separately (:mod:`.dialogs`), so the same route can be phrased with any family of
sentence frames. Facts are plain data and round-trip through JSON (``DIALOGS.json``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.geometry import point_in_view_strict
from skyvln_eval.worlds.city.plan import LandmarkSpec
from skyvln_eval.worlds.sample.pilot import PlanGeo
from skyvln_eval.worlds.sample.routes import Route, compass_bearing

CARDINALS = ("north", "northeast", "east", "southeast", "south", "southwest", "west", "northwest")
CATEGORY_WORDS = {
    "restaurant": "restaurant",
    "church": "church",
    "stadium": "stadium",
    "gas_station": "gas station",
    "roundabout": "roundabout",
    "bridge": "bridge",
    "park": "park",
    "school": "school",
    "hospital": "hospital",
    "mall": "shopping mall",
    "hotel": "hotel",
    "tower": "tall tower",
    "water_tower": "water tower",
}
#: Landmarks whose proper name a commander would not add (it names a street or a place).
UNNAMED_CATEGORIES = ("park", "bridge", "roundabout")

Side = Literal["left", "right", "ahead"]
QuestionKind = Literal["which_way", "keep", "close", "is_it", "can_see"]


def cardinal(bearing_deg: float) -> str:
    return CARDINALS[int(((bearing_deg % 360) + 22.5) // 45) % 8]


def side_of(route_bearing: float, from_xy: NDArray[np.float64], to_xy: NDArray[np.float64]) -> Side:
    """'left', 'right' or 'ahead' of a traveller heading ``route_bearing``."""
    delta = (compass_bearing(from_xy, to_xy) - route_bearing + 180.0) % 360.0 - 180.0
    if delta > 25:
        return "right"
    if delta < -25:
        return "left"
    return "ahead"


@dataclass(frozen=True)
class LandmarkFact:
    """A landmark as the commander refers to it: full description, category word, name."""

    landmark_id: int
    description: str
    word: str
    name: str | None = None


@dataclass(frozen=True)
class TurnFact:
    """A turn at an intersection: the ``ordinal``-th one of the round (0: the next one), or
    the one by landmark ``at`` (a roundabout when ``roundabout``)."""

    direction: Literal["left", "right"]
    ordinal: int = 0
    at: LandmarkFact | None = None
    roundabout: bool = False


@dataclass(frozen=True)
class PassFact:
    landmark: LandmarkFact
    side: Side


@dataclass(frozen=True)
class QuestionFact:
    """The follower's question opening a later round: its kind, the compass point the
    follower flew last, the one the next round starts with, and a landmark near it."""

    kind: QuestionKind
    heading: str
    next_heading: str
    word: str | None = None


@dataclass(frozen=True)
class RoundFacts:
    """Everything one round's instruction says, in the order it says it."""

    heading: str
    along_road: bool
    turns: tuple[TurnFact, ...]
    passing: PassFact | None
    distance_m: int
    destination: LandmarkFact | None = None
    destination_distance: bool = False
    stop_at: LandmarkFact | None = None
    question: QuestionFact | None = None

    @property
    def mentioned_ids(self) -> tuple[int, ...]:
        """Landmarks the instruction mentions, in order (attention circles follow them)."""
        ids = [t.at.landmark_id for t in self.turns if t.at is not None]
        ids += [self.passing.landmark.landmark_id] if self.passing else []
        ids += [lm.landmark_id for lm in (self.destination, self.stop_at) if lm is not None]
        return tuple(ids)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RoundFacts:
        def landmark(d: dict[str, Any] | None) -> LandmarkFact | None:
            return None if d is None else LandmarkFact(**d)

        passing = data.get("passing")
        question = data.get("question")
        return cls(
            heading=data["heading"],
            along_road=data["along_road"],
            turns=tuple(
                TurnFact(t["direction"], t["ordinal"], landmark(t["at"]), t["roundabout"])
                for t in data["turns"]
            ),
            passing=None
            if passing is None
            else PassFact(LandmarkFact(**passing["landmark"]), passing["side"]),
            distance_m=data["distance_m"],
            destination=landmark(data.get("destination")),
            destination_distance=data.get("destination_distance", False),
            stop_at=landmark(data.get("stop_at")),
            question=None if question is None else QuestionFact(**question),
        )


class FactFinder:
    """Draws the facts of every round of one trajectory from its random stream.

    The draws are the ones version 1 of the generator made, in the same order, so routes
    drawn later from the same stream are unchanged; the wording moved to its own stream.
    """

    def __init__(
        self, rng: np.random.Generator, route: Route, geo: PlanGeo, landmarks: list[LandmarkSpec]
    ) -> None:
        self.rng = rng
        self.route = route
        self.geo = geo
        self.landmarks = landmarks

    @staticmethod
    def fact(lm: LandmarkSpec, with_name: bool = False) -> LandmarkFact:
        named = with_name and lm.category not in UNNAMED_CATEGORIES
        word = CATEGORY_WORDS.get(lm.category, lm.category)
        return LandmarkFact(lm.landmark_id, lm.description, word, lm.name if named else None)

    def visible(self, views: list[NDArray[np.float64]], exclude: set[int]) -> list[LandmarkSpec]:
        centres = self.geo.to_latlng(np.array([lm.polygon.mean(axis=0) for lm in self.landmarks]))
        seen = np.zeros(len(self.landmarks), bool)
        for view in views:
            seen |= np.asarray(point_in_view_strict(centres, view))
        return [
            lm
            for lm, s in zip(self.landmarks, seen, strict=True)
            if s and lm.landmark_id not in exclude
        ]

    def turns(self, s0: float, s1: float) -> list[tuple[float, Literal["left", "right"]]]:
        out: list[tuple[float, Literal["left", "right"]]] = []
        for s in self.route.node_s:
            if s0 + 10 < s < s1 - 5:
                before = self.route.bearing_at(s - 20.0, 20.0)
                after = self.route.bearing_at(s, 20.0)
                delta = (after - before + 180.0) % 360.0 - 180.0
                if abs(delta) > 35:
                    out.append((s, "right" if delta > 0 else "left"))
        return out

    def intersections_before(self, s0: float, s: float) -> int:
        return sum(1 for t in self.route.node_s if s0 + 10 < t <= s + 1)

    def round_facts(self, r: int, views: list[NDArray[np.float64]], used: set[int]) -> RoundFacts:
        """The facts of round ``r`` (0-based): where to go and where to stop."""
        s0 = 0.0 if r == 0 else self.route.stop_s[r - 1]
        s1 = self.route.stop_s[r]
        final = r == len(self.route.stop_s) - 1
        # Of version 1's four heading phrasings, the first two mentioned the road.
        along_road = int(self.rng.integers(4)) < 2
        turns: list[TurnFact] = []
        mentioned: set[int] = set()
        for s, direction in self.turns(s0, s1)[:2]:
            nth = min(self.intersections_before(s0, s), 4)
            at = self._landmark_near(self.route.point_at(s), 45.0, used | mentioned)
            if at is not None and at.category == "roundabout":
                turns.append(TurnFact(direction, nth, self.fact(at), roundabout=True))
                mentioned.add(at.landmark_id)
            elif at is not None and self.rng.random() < 0.6:
                turns.append(TurnFact(direction, nth, self.fact(at)))
                mentioned.add(at.landmark_id)
            else:
                turns.append(TurnFact(direction, nth))
        passing = None
        candidates = [
            lm
            for lm in self.visible(views, used | mentioned)
            if lm.landmark_id != self.route.destination.landmark_id
        ]
        if candidates and self.rng.random() < 0.8:
            lm = candidates[int(self.rng.integers(len(candidates)))]
            closest = self._closest_s(lm, s0, s1)
            side = side_of(
                self.route.bearing_at(closest),
                self.route.point_at(closest),
                lm.polygon.mean(axis=0),
            )
            self.rng.integers(2)  # version 1 drew this clause's wording here
            passing = PassFact(self.fact(lm), side)
            mentioned.add(lm.landmark_id)
        heading = cardinal(self.route.bearing_at(s0, 25.0))
        facts = RoundFacts(heading, along_road, tuple(turns), passing, self._metres(s0, s1))
        if final:
            with_name = self.rng.random() < 0.35
            # Version 1's third destination phrasing was the one that said how far it is.
            with_distance = int(self.rng.integers(3)) == 2
            dest = self.fact(self.route.destination, with_name)
            return replace(facts, destination=dest, destination_distance=with_distance)
        near = self._landmark_near(self.route.point_at(s1), 60.0, used | mentioned)
        if near is not None and near.landmark_id != self.route.destination.landmark_id:
            return replace(facts, stop_at=self.fact(near))
        self.rng.integers(2)  # version 1 drew this clause's wording here
        return facts

    def question(self, r: int) -> QuestionFact:
        """The follower's question at the start of round ``r`` (>= 1)."""
        s = self.route.stop_s[r - 1]
        heading = cardinal(self.route.bearing_at(max(0.0, s - 20), 20))
        next_heading = cardinal(self.route.bearing_at(s, 25))
        near = self._landmark_near(self.route.point_at(s), 120.0, set())
        kinds: list[QuestionKind] = ["which_way", "keep", "close"]
        word = None
        if near is not None and near.landmark_id != self.route.destination.landmark_id:
            kinds += ["is_it", "can_see"]
            word = CATEGORY_WORDS.get(near.category, near.category)
        kind = kinds[int(self.rng.integers(len(kinds)))]
        return QuestionFact(
            kind, heading, next_heading, word if kind in ("is_it", "can_see") else None
        )

    @staticmethod
    def _metres(s0: float, s1: float) -> int:
        return int(round((s1 - s0) / 50.0) * 50) or 50

    def _landmark_near(
        self, xy: NDArray[np.float64], radius: float, exclude: set[int]
    ) -> LandmarkSpec | None:
        best, best_d = None, radius
        for lm in self.landmarks:
            if lm.landmark_id in exclude:
                continue
            d = float(np.linalg.norm(lm.polygon.mean(axis=0) - xy))
            if d < best_d:
                best, best_d = lm, d
        return best

    def _closest_s(self, lm: LandmarkSpec, s0: float, s1: float) -> float:
        samples = np.linspace(s0, s1, 24)
        centre = lm.polygon.mean(axis=0)
        return float(
            samples[
                int(np.argmin([np.linalg.norm(self.route.point_at(s) - centre) for s in samples]))
            ]
        )
