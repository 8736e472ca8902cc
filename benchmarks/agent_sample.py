"""Benchmark: the SkyVLN agent, its ablations and the baselines on the sample, official mode.

Runs every system on the ANDH episodes of the synthetic sample's val_seen, val_unseen and
test_unseen splits (the sample keeps test_unseen's ground truth) with the official step,
at most 10 views per episode, and prints per split: success rate (AVDN success:
hull-IoU >= 0.4 and both centres strictly inside the other view), navigation error
(final centre to ground-truth end centre, m), mean actions and LLM calls per episode, and
how the ablations' behaviour differs from the full agent's (episodes whose actions
differ, fly-tos, memory way-backs). All LLM calls go to the offline ``rule`` backend,
which is rule-based, not an LLM: the figures measure the pipeline, not a language model.

    python benchmarks/agent_sample.py [--splits val_seen,val_unseen,test_unseen] [--limit N]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from skyvln_eval.agent import AgentConfig, FlyTo, action_record, build_agent
from skyvln_eval.avdn import Episode, distance_m, load_split, view_centre
from skyvln_eval.harness import OfficialRollout, run_official_episode
from skyvln_eval.harness.oracle import ground_truth_oracle
from skyvln_eval.metrics import view_success
from skyvln_eval.worlds import WorldTile, load_world
from skyvln_eval.worlds.sample import ensure_sample

SYSTEMS: dict[str, AgentConfig] = {
    "SkyVLN full (rule)": AgentConfig(),
    "w/o HSD (rule)": AgentConfig(hsd=False),
    "w/o TBMA (rule)": AgentConfig(tbma=False),
    "NavGPT-style (rule)": AgentConfig(name="navgpt"),
    "random": AgentConfig(name="random"),
    "ground-truth replay (oracle)": AgentConfig(name="ground_truth"),
}
FULL = "SkyVLN full (rule)"


@dataclass
class Tally:
    success: list[bool] = field(default_factory=list)
    error_m: list[float] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    calls: list[int] = field(default_factory=list)
    fly_tos: int = 0
    way_backs: int = 0
    seconds: float = 0.0
    plans: list[list[dict[str, object]]] = field(default_factory=list)

    def add(self, rollout: OfficialRollout, episode: Episode) -> None:
        self.success.append(view_success(rollout.final_view, episode.gt_end_view))
        gap = distance_m(view_centre(rollout.final_view), view_centre(episode.gt_end_view))
        self.error_m.append(float(gap))
        self.actions.append(len(rollout.actions))
        self.calls.append(len(rollout.llm_calls))
        self.fly_tos += sum(isinstance(a, FlyTo) for a in rollout.actions)
        self.way_backs += sum(1 for t in rollout.traces if t.get("way_back"))
        self.plans.append([action_record(a) for a in rollout.actions])


def run_split(split: str, limit: int | None, worlds: dict[str, WorldTile]) -> dict[str, Tally]:
    data_dir = ensure_sample()
    episodes = load_split(data_dir, split).episodes("andh")[:limit]
    tallies = {name: Tally() for name in SYSTEMS}
    for episode in episodes:  # before any clock starts: else the first system pays for all
        if episode.map_name not in worlds:
            worlds[episode.map_name] = load_world(data_dir, episode.map_name, episode.georef)
    for name, config in SYSTEMS.items():
        oracle = config.name == "ground_truth"  # the replay reads the route: built per episode
        agent = None if oracle else build_agent(config)
        start = time.perf_counter()
        for episode in episodes:
            flying = ground_truth_oracle(episode) if agent is None else agent
            run = run_official_episode(flying, episode, worlds[episode.map_name])
            tallies[name].add(run, episode)
        tallies[name].seconds = time.perf_counter() - start
    return tallies


def report(split: str, tallies: dict[str, Tally]) -> None:
    n = len(tallies[FULL].success)
    print(f"\n{split}: {n} ANDH episodes")
    row = "{:<30} {:>6} {:>7} {:>8} {:>9} {:>8} {:>10} {:>8} {:>7}"
    print(
        row.format(
            "system",
            "SR %",
            "NE m",
            "actions",
            "LLM calls",
            "fly-tos",
            "way-backs",
            "differ",
            "s/ep",
        )
    )
    full = tallies[FULL].plans
    mean: Callable[[Sequence[float]], float] = lambda xs: float(np.mean(xs)) if xs else 0.0  # noqa: E731
    for name, t in tallies.items():
        differ = sum(a != b for a, b in zip(t.plans, full, strict=True))
        print(
            row.format(
                name,
                f"{100 * mean(t.success):.1f}",
                f"{np.median(t.error_m):.0f}",
                f"{mean(t.actions):.1f}",
                f"{mean(t.calls):.1f}",
                t.fly_tos,
                t.way_backs,
                "-" if name == FULL else f"{differ}/{n}",
                f"{t.seconds / max(n, 1):.2f}",
            )
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--splits", default="val_seen,val_unseen,test_unseen")
    parser.add_argument("--limit", type=int, default=None, help="episodes per split (default all)")
    args = parser.parse_args()
    worlds: dict[str, WorldTile] = {}
    totals: dict[str, list[bool]] = {name: [] for name in SYSTEMS}
    for split in args.splits.split(","):
        tallies = run_split(split, args.limit, worlds)
        report(split, tallies)
        for name, t in tallies.items():
            totals[name] += t.success
    print(
        "\nall splits: "
        + ", ".join(f"{name} SR {100 * np.mean(s):.1f}%" for name, s in totals.items())
    )
    print(
        "(NE: median navigation error; differ: episodes whose actions differ from the full agent's)"
    )


if __name__ == "__main__":
    main()
