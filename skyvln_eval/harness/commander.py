"""A commander in the loop: answers the agent's clarification questions from the ground truth.

In AVDN the commander sees the map and the drone, and answers the follower's questions.
When the agent asks (TrackBack memory lost its way, or HSD could not tell the stop
landmark apart), the harness's :class:`SimulatedCommander` answers, at most
``max_questions`` times per episode, in the synthetic commander's language (the phrasing
families of the episode's split): which way to the episode's goal from where the drone is
and how far, or, once the drone's view would be a success there (AVDN's test: the views
overlap by 0.4 of their hull and each holds the other's centre), that it is there and
should stop. (Said within half a view of the goal, it told agents to stop where they
then failed: an audit saw it lower the full agent's SR by 3.3 points.)

The goal is the end of the ground truth the episode is scored against. In an ANDH
episode of an intermediate round that is the round's end: on the synthetic data the place
the round's instruction leads to ("fly 100 m and wait"), on AVDN's the point where the
human follower stopped, which a human commander did not know in advance (the tables say
the commander "knows the goal"). So the commander names a landmark there as *the
destination* only on a trajectory's last round (``last_round_idx``); before it, it says
how far to go and to stop, as the round's instruction does. The question and the answer
join the dialog the agent sees at its next step, as a new round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.geometry import view_centre
from skyvln_eval.avdn.records import DialogTurn, Episode
from skyvln_eval.frames import latlng_to_enu, view_to_pose
from skyvln_eval.harness.seeds import derived_seed
from skyvln_eval.metrics.official import view_success
from skyvln_eval.worlds.sample import SPLIT_FAMILIES, AnswerFacts, commander_answer, seen_families

# The generator's own compass names: the commander's writing shares no code with the
# stand-in's reader (skyvln_eval.vocabulary).
from skyvln_eval.worlds.sample.facts import cardinal
from skyvln_eval.worlds.tile import WorldTile

#: A heading more than this far off the way to the destination is a wrong heading.
WRONG_HEADING_DEG = 100.0


@dataclass
class SimulatedCommander:
    """Answers questions about one episode (see the module docstring)."""

    episode: Episode
    world: WorldTile
    max_questions: int = 2
    seed: int = 0
    answered: int = 0

    def __post_init__(self) -> None:
        self._round = max((t.round_index for t in self.episode.dialog()), default=1)
        families = SPLIT_FAMILIES.get(self.episode.split)
        self._families = families if families else seen_families()
        self._destination = self._destination_description()

    def _ends_the_trajectory(self) -> bool:
        """Whether the episode's goal is the trajectory's last view (its last round)."""
        last = self.episode.records[-1]
        return last.last_round_idx is not None and last.round_index == last.last_round_idx

    def _half_edge_m(self) -> float:
        """Half the front edge of the goal view, in the official metres."""
        end = self.episode.gt_end_view
        return float(np.linalg.norm(end[0] - end[1])) * METERS_PER_DEGREE / 2.0

    def _destination_description(self) -> str | None:
        """The landmark the trajectory ends over, on its last round, if the map knows its
        landmarks (``None`` on earlier rounds: their ends are not the destination)."""
        if not self._ends_the_trajectory():
            return None
        centre = np.asarray(view_centre(self.episode.gt_end_view), dtype=np.float64)
        best: tuple[float, str] | None = None
        for landmark in self.world.landmarks:
            gap = math.hypot(*(np.asarray(landmark.centre) - centre)) * METERS_PER_DEGREE
            if best is None or gap < best[0]:
                best = (gap, landmark.description)
        return best[1] if best is not None and best[0] <= self._half_edge_m() else None

    def answer(
        self, step_index: int, question: str, view: NDArray[np.float64]
    ) -> tuple[DialogTurn, ...]:
        """The question and the answer as a new dialog round (nothing once over budget)."""
        if self.answered >= self.max_questions:
            return ()
        georef = self.episode.georef
        here = view_to_pose(view, georef)
        goal_x, goal_y = latlng_to_enu(view_centre(self.episode.gt_end_view), georef)
        east, north = goal_x - here.x_m, goal_y - here.y_m
        bearing = math.degrees(math.atan2(east, north)) % 360.0
        off = abs((here.heading_deg - bearing + 180.0) % 360.0 - 180.0)
        distance_m = math.hypot(east, north)
        facts = AnswerFacts(
            direction=cardinal(bearing),
            distance_m=distance_m,
            landmark=self._destination,
            is_destination=self._destination is not None,
            wrong_heading=cardinal(here.heading_deg) if off > WRONG_HEADING_DEG else None,
            arrived=view_success(view, self.episode.gt_end_view),
        )
        seed = derived_seed(self.seed, "commander", self.episode.episode_id, step_index)
        text = commander_answer(facts, self._families, seed).text
        self.answered += 1
        self._round += 1
        return (
            DialogTurn(self._round, "follower", question),
            DialogTurn(self._round, "commander", text),
        )
