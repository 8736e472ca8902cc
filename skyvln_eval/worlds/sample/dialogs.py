"""Commander / follower dialogs for synthetic trajectories, from templates.

Instructions mention what a commander looking at the map would: compass directions,
turns at intersections, distances, landmarks actually inside the ground-truth views
(with the side they are on) and the destination's appearance. Later rounds open with
the follower's question (``[QUE]``) and the commander's answer (``[INS]``), as in AVDN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.geometry import point_in_view_strict
from skyvln_eval.worlds.city.plan import LandmarkSpec
from skyvln_eval.worlds.sample.pilot import PlanGeo
from skyvln_eval.worlds.sample.routes import Route, compass_bearing

CARDINALS = ("north", "northeast", "east", "southeast", "south", "southwest", "west", "northwest")
ORDINALS = ("first", "second", "third", "fourth")
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


def cardinal(bearing_deg: float) -> str:
    return CARDINALS[int(((bearing_deg % 360) + 22.5) // 45) % 8]


def side_of(route_bearing: float, from_xy: NDArray[np.float64], to_xy: NDArray[np.float64]) -> str:
    """'left', 'right' or 'ahead' of a traveller heading ``route_bearing``."""
    delta = (compass_bearing(from_xy, to_xy) - route_bearing + 180.0) % 360.0 - 180.0
    if delta > 25:
        return "right"
    if delta < -25:
        return "left"
    return "ahead"


@dataclass(frozen=True)
class RoundText:
    instructions: str
    mentioned: tuple[LandmarkSpec, ...]


class DialogWriter:
    """Writes every round of one trajectory."""

    def __init__(
        self, rng: np.random.Generator, route: Route, geo: PlanGeo, landmarks: list[LandmarkSpec]
    ) -> None:
        self.rng = rng
        self.route = route
        self.geo = geo
        self.landmarks = landmarks

    def pick(self, options: tuple[str, ...] | list[str]) -> str:
        return str(options[int(self.rng.integers(len(options)))])

    def phrase(self, lm: LandmarkSpec, with_name: bool = False) -> str:
        text = lm.description
        if with_name and lm.category not in ("park", "bridge", "roundabout"):
            text += f" ({lm.name})"
        return text

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

    def turns(self, s0: float, s1: float) -> list[tuple[float, str]]:
        out = []
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

    def segment(self, r: int, views: list[NDArray[np.float64]], used: set[int]) -> RoundText:
        """The instruction part for round ``r`` (0-based): where to go and where to stop."""
        s0 = 0.0 if r == 0 else self.route.stop_s[r - 1]
        s1 = self.route.stop_s[r]
        final = r == len(self.route.stop_s) - 1
        heading = self.route.bearing_at(s0, 25.0)
        parts = [
            self.pick(
                (
                    f"head {cardinal(heading)} along the road",
                    f"fly {cardinal(heading)} following the street",
                    f"go {cardinal(heading)}",
                    f"move towards the {cardinal(heading)}",
                )
            )
        ]
        mentioned: list[LandmarkSpec] = []
        for s, direction in self.turns(s0, s1)[:2]:
            nth = self.intersections_before(s0, s)
            at = self._landmark_near(
                self.route.point_at(s), 45.0, used | {m.landmark_id for m in mentioned}
            )
            if at is not None and at.category == "roundabout":
                parts.append(f"at the roundabout take the {direction}")
                mentioned.append(at)
            elif at is not None and self.rng.random() < 0.6:
                word = CATEGORY_WORDS.get(at.category, at.category)
                parts.append(f"turn {direction} at the intersection by the {word}")
                mentioned.append(at)
            else:
                which = ORDINALS[min(nth, 4) - 1] if nth else "next"
                parts.append(f"turn {direction} at the {which} intersection")
        passing = [
            lm
            for lm in self.visible(views, used | {m.landmark_id for m in mentioned})
            if lm.landmark_id != self.route.destination.landmark_id
        ]
        if passing and self.rng.random() < 0.8:
            lm = passing[int(self.rng.integers(len(passing)))]
            closest = self._closest_s(lm, s0, s1)
            side = side_of(
                self.route.bearing_at(closest),
                self.route.point_at(closest),
                lm.polygon.mean(axis=0),
            )
            where = "in front of you" if side == "ahead" else f"on your {side}"
            parts.append(
                self.pick(
                    (f"you will pass {self.phrase(lm)} {where}", f"keep {self.phrase(lm)} {where}")
                )
            )
            mentioned.append(lm)
        metres = int(round((s1 - s0) / 50.0) * 50) or 50
        if final:
            dest = self.route.destination
            with_name = self.rng.random() < 0.35
            parts.append(
                self.pick(
                    (
                        f"the destination is {self.phrase(dest, with_name)}",
                        f"stop over {self.phrase(dest, with_name)}, that is the destination",
                        f"after about {metres} meters you will see {self.phrase(dest, with_name)}; "
                        "that is your destination",
                    )
                )
            )
            mentioned.append(dest)
        else:
            near = self._landmark_near(
                self.route.point_at(s1), 60.0, used | {m.landmark_id for m in mentioned}
            )
            if near is not None and near.landmark_id != self.route.destination.landmark_id:
                parts.append(
                    f"stop when you reach the {CATEGORY_WORDS.get(near.category, near.category)}"
                )
                mentioned.append(near)
            else:
                parts.append(
                    self.pick(
                        (
                            f"stop after about {metres} meters",
                            f"fly about {metres} meters and wait there",
                        )
                    )
                )
        sentences = [", ".join(parts[:-1]), parts[-1]] if len(parts) > 1 else parts
        text = " ".join(sentence[0].upper() + sentence[1:] + "." for sentence in sentences)
        return RoundText(text, tuple(mentioned))

    def question(self, r: int) -> tuple[str, str]:
        """The follower's question at the start of round ``r`` (>= 1) and the answer's opening."""
        s = self.route.stop_s[r - 1]
        heading = self.route.bearing_at(max(0.0, s - 20), 20)
        next_heading = self.route.bearing_at(s, 25)
        near = self._landmark_near(self.route.point_at(s), 120.0, set())
        options = [
            ("I am at the stop, which way should I go now?", "Go on"),
            (
                f"Should I keep flying {cardinal(heading)}?",
                "Yes, keep going" if cardinal(heading) == cardinal(next_heading) else "No",
            ),
            ("Am I close to the destination?", "Not yet"),
        ]
        if near is not None and near.landmark_id != self.route.destination.landmark_id:
            word = CATEGORY_WORDS.get(near.category, near.category)
            options.append((f"Is the destination the {word} near me?", "No, it is not"))
            options.append((f"I can see the {word}. Where to now?", "Good"))
        q, a = options[int(self.rng.integers(len(options)))]
        return q, a

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


def attention_circles(
    geo: PlanGeo, mentioned: tuple[LandmarkSpec, ...], stop_xy: NDArray[np.float64], mpp: float
) -> list[list[object]]:
    """Attention circles ``[[lat, lng], radius_px]`` on mentioned landmarks and the stop."""
    circles: list[list[object]] = []
    for lm in mentioned:
        extent = float(np.ptp(lm.polygon, axis=0).max())
        lat, lng = (float(v) for v in geo.to_latlng(lm.polygon.mean(axis=0)))
        circles.append([[lat, lng], int(np.clip(extent / mpp / 2, 15, 150))])
    lat, lng = (float(v) for v in geo.to_latlng(stop_xy))
    circles.append([[lat, lng], round(40 / mpp)])
    return circles
