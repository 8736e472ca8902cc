"""Benchmark: how much does the simulated commander give away?

The commander answers an agent's questions from the ground truth: the way and distance to
the goal, or that the drone is there (harness/commander.py; AVDN's human commanders say
such things too). A system that asks more is helped more, so a table compares systems
fairly only at the same ``commander.max_questions``, and its notes say who asked what.

This flies a *blind beacon* over the synthetic sample's ANDH episodes: an agent that
reads nothing but the commander's answers (no camera, no instruction), asks at every
step, and flies the way and distance it was last told, stopping when told it is there
or when it has flown the distance. Its success rate is what the answers alone are
worth; next to it, rule Full (the SkyVLN agent on the offline rule stand-in) with the
same commander. Rows for each ``--questions`` budget (default 0 and 2, the default).

    python benchmarks/commander.py [--questions 0,2] [--splits val_seen,val_unseen,test_unseen]
                                   [--limit N]
"""

from __future__ import annotations

import argparse
import functools
import math
import re
import time

import numpy as np

from skyvln_eval.agent import AgentConfig, build_agent
from skyvln_eval.agent.actions import Stop, Waypoint
from skyvln_eval.agent.base import Agent, Decision, EpisodeBrief, Observation
from skyvln_eval.avdn import Episode, load_split
from skyvln_eval.avdn.constants import METERS_PER_DEGREE
from skyvln_eval.avdn.geometry import view_centre
from skyvln_eval.avdn.imagery import MapGeoref
from skyvln_eval.harness import run_official_episode
from skyvln_eval.harness.commander import SimulatedCommander
from skyvln_eval.metrics import view_success
from skyvln_eval.vocabulary import COMPASS, compass_points_in
from skyvln_eval.vocabulary.quantities import distances_in
from skyvln_eval.worlds import WorldTile, load_world
from skyvln_eval.worlds.sample import ensure_sample

#: Words and numbers of an answer, a number glued to its unit ("150m") split from it.
_TOKENS = re.compile(r"\d+(?:\.\d+)?|[a-z]+")


class BlindBeacon(Agent):
    """Flies the commander's last answer and nothing else (see the module docstring)."""

    name = "blind_beacon"

    def reset(self, brief: EpisodeBrief) -> None:
        self._bearing_deg: float | None = None
        self._left_m = 0.0

    def act(self, observation: Observation) -> Decision:
        answers = [t.text for t in observation.new_dialog if t.speaker == "commander"]
        if answers:
            words = _TOKENS.findall(answers[-1].lower())
            points = compass_points_in(words)
            if not points:  # no way to go: "you are there"
                return Decision("told I am there", Stop())
            distances = distances_in(words)
            self._bearing_deg = COMPASS[points[-1][1]]
            self._left_m = distances[-1][1] if distances else 50.0
        ask = "Which way to the destination?"
        if self._bearing_deg is None:  # nothing told yet (no answer, or none left)
            if observation.step_index == 0:
                return Decision("asking", Waypoint(0.0, 0.0, _altitude(observation)), question=ask)
            return Decision("never told", Stop())
        if self._left_m <= 15.0:
            return Decision("flew what I was told", Stop())
        half_m = observation.pose.edge_m / 2.0
        step_m = min(self._left_m, half_m)
        self._left_m -= step_m
        turn = math.radians(self._bearing_deg - observation.pose.heading_deg)
        right, forward = math.sin(turn) * step_m / half_m, math.cos(turn) * step_m / half_m
        waypoint = Waypoint(right, forward, _altitude(observation))
        return Decision("flying the answer", waypoint, question=ask)


def _altitude(observation: Observation) -> float:
    """The current height as AVDN's altitude fraction (view edge 40 m .. 400 m)."""
    return min(1.0, max(0.0, (observation.pose.edge_m - 40.0) / 360.0))


@functools.cache
def _world(map_name: str, georef: MapGeoref) -> WorldTile:
    return load_world(ensure_sample(), map_name, georef)


def fly(agent: Agent, episodes: list[Episode], questions: int) -> tuple[float, float, float, float]:
    """SR (%), median NE (m), answers per episode and seconds per episode."""
    wins, errors_m, answered = [], [], []
    for episode in episodes:  # loaded before the clock starts: else the first row pays
        _world(episode.map_name, episode.georef)
    started = time.perf_counter()
    for episode in episodes:
        world = _world(episode.map_name, episode.georef)
        commander = SimulatedCommander(episode, world, questions) if questions else None
        rollout = run_official_episode(agent, episode, world, commander=commander)
        wins.append(view_success(rollout.final_view, episode.gt_end_view))
        gap = view_centre(rollout.final_view) - view_centre(episode.gt_end_view)
        errors_m.append(float(np.linalg.norm(gap)) * METERS_PER_DEGREE)
        answered.append(commander.answered if commander else 0)
    seconds = (time.perf_counter() - started) / max(1, len(episodes))
    return (
        100.0 * float(np.mean(wins)),
        float(np.median(errors_m)),
        float(np.mean(answered)),
        seconds,
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--questions", default="0,2", help="max_questions budgets")
    parser.add_argument("--splits", default="val_seen,val_unseen,test_unseen")
    parser.add_argument("--limit", type=int, default=None, help="episodes per split")
    args = parser.parse_args()
    data_dir = ensure_sample()
    episodes = [
        Episode(split=split, mode="andh", records=(record,))
        for split in args.splits.split(",")
        for record in load_split(data_dir, split).records[: args.limit]
    ]
    print(f"sample: {data_dir}; {len(episodes)} ANDH episodes of {args.splits}")
    row = "{:<34} {:>9} {:>6} {:>10} {:>9} {:>6}"
    print(row.format("agent", "questions", "SR %", "median NE", "answers", "s/ep"))
    agents = {
        "blind beacon (answers only)": BlindBeacon(),
        "rule Full (SkyVLN, rule stand-in)": build_agent(AgentConfig()),
    }
    for questions in (int(q) for q in args.questions.split(",")):
        for label, agent in agents.items():
            sr, ne_m, answers, seconds = fly(agent, episodes, questions)
            figures = (f"{sr:.1f}", f"{ne_m:.0f} m", f"{answers:.2f}", f"{seconds:.2f}")
            print(row.format(label, questions, *figures))


if __name__ == "__main__":
    main()
