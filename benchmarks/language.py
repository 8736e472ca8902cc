"""Benchmark: does the rule stand-in read language, or know its generator's sentences?

Flies the SkyVLN agent with every part on ("Full") and the offline ``rule`` backend
(rule-based, not an LLM) in official mode over the ANDH episodes of the synthetic
sample, three times per split, on the same routes and ground truth:

- as generated: each split in its own families of sentence frames;
- seen-style: every dialog rephrased by the families of the seen splits (train, val_seen);
- validation-style: rephrased by val_unseen's families (validation phrasings: the
  reader's tests read them, so they are not held out);
- held-out: rephrased by test_unseen's families only (no test reads them, and the idioms
  only they use are not in the reader's vocabulary).

It prints the success rate of each (AVDN success: hull-IoU >= 0.4 and both centres
strictly inside the other view), the gap seen-style minus held-out, and the number of
distinct sentence frames each split's dialogs use in each phrasing. ``--families``
adds one row per single family.

    python benchmarks/language.py [--splits val_seen,val_unseen,test_unseen] [--limit N]
                                  [--families]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence

import numpy as np

from skyvln_eval.agent import AgentConfig, build_agent
from skyvln_eval.avdn import AvdnRecord, Episode, load_split
from skyvln_eval.harness import run_official_episode
from skyvln_eval.metrics import view_success
from skyvln_eval.worlds import WorldTile, load_world
from skyvln_eval.worlds.sample import (
    FAMILIES,
    SPLIT_FAMILIES,
    DialogSources,
    ensure_sample,
    load_dialogs,
    render_trajectory,
    rephrase_records,
    seen_families,
)


def frames_in(
    sources: DialogSources, split: str, families: Sequence[str], records: Sequence[AvdnRecord]
) -> int:
    """Distinct sentence frames of the dialogs of ``records`` (of ``split``) when
    ``families`` phrase them."""
    wanted = {(r.map_name, r.trajectory_index) for r in records}
    used = set()
    for t in sources.trajectories[split]:
        if (t.map_name, t.trajectory) not in wanted:
            continue
        for utterance in render_trajectory(t.rounds, families, t.wording_seed):
            used |= set(utterance.frames)
    return len(used)


def success_rate(
    records: Sequence[AvdnRecord], split: str, worlds: dict[str, WorldTile]
) -> tuple[float, float]:
    """SR (%) of rule Full over ANDH episodes of ``records``, and seconds per episode."""
    data_dir = ensure_sample()
    agent = build_agent(AgentConfig())  # SkyVLN, HSD and TBMA on, rule backend
    episodes = [Episode(split=split, mode="andh", records=(record,)) for record in records]
    for episode in episodes:  # loaded before the clock starts: else the first row pays
        if episode.map_name not in worlds:
            worlds[episode.map_name] = load_world(data_dir, episode.map_name, episode.georef)
    wins = []
    started = time.perf_counter()
    for episode in episodes:
        rollout = run_official_episode(agent, episode, worlds[episode.map_name])
        wins.append(view_success(rollout.final_view, episode.gt_end_view))
    seconds = (time.perf_counter() - started) / max(1, len(records))
    return 100.0 * float(np.mean(wins)) if wins else float("nan"), seconds


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--splits", default="val_seen,val_unseen,test_unseen")
    parser.add_argument("--limit", type=int, default=None, help="episodes per split (default all)")
    parser.add_argument("--families", action="store_true", help="also one row per family")
    args = parser.parse_args()
    data_dir = ensure_sample()
    sources = load_dialogs(data_dir)
    seen = seen_families()
    validation, held_out = SPLIT_FAMILIES["val_unseen"], SPLIT_FAMILIES["test_unseen"]
    print(f"sample: {data_dir}")
    print(
        f"seen-style families: {', '.join(seen)}; validation-style: {', '.join(validation)}; "
        f"held-out: {', '.join(held_out)}"
    )
    print("system: SkyVLN Full, rule backend (rule-based, not an LLM), official mode\n")
    phrasings: dict[str, tuple[str, ...] | None] = {
        "as generated": None,
        "seen-style": seen,
        "validation-style": validation,
        "held-out": held_out,
    }
    if args.families:
        phrasings |= {f"family {name}": (name,) for name in FAMILIES}
    worlds: dict[str, WorldTile] = {}
    row = "{:<12} {:>5} {:<22} {:>7} {:>7} {:>6}"
    print(row.format("split", "eps", "phrasing", "SR %", "frames", "s/ep"))
    gaps = []
    for split in args.splits.split(","):
        records = list(load_split(data_dir, split).records[: args.limit])
        rates = {}
        for label, families in phrasings.items():
            own = families is None
            chosen = SPLIT_FAMILIES[split] if families is None else families
            phrased = records if own else rephrase_records(records, sources, split, chosen)
            rates[label], seconds = success_rate(phrased, split, worlds)
            frames = frames_in(sources, split, chosen, records)
            print(
                row.format(
                    split, len(records), label, f"{rates[label]:.1f}", frames, f"{seconds:.2f}"
                )
            )
        gap = rates["seen-style"] - rates["held-out"]
        gaps.append(gap)
        print(row.format(split, "", "gap seen - held-out", f"{gap:+.1f}", "", ""))
    print(f"\nmean gap (seen-style minus held-out): {np.mean(gaps):+.1f} points")
    print("(frames: distinct sentence frames the dialogs of these episodes use in that phrasing)")


if __name__ == "__main__":
    main()
