"""Benchmark: the simulated detector on the 5 views of a decision, against the old algorithm.

Renders the panorama (4 headings and the view straight down, the agent's default) from
every ground-truth view of the ANDH episodes of the synthetic sample's val_seen split,
until ``--decisions`` decisions (5 captures each), then runs
:class:`~skyvln_eval.agent.detectors.SimulatedDetector` over them episode by episode (reset
with the episode's seed, as the agent does, so buildings met earlier in the episode are
remembered) and, as the baseline in the same process, the detector's algorithm as it was
before it was vectorised (a Python loop over every plain building: its pixels, its points
and medians one by one, a linear scan of the buildings met), the reference its test
compares with (``tests/agent/detector_reference.py``, not in the package). Old and new
passes alternate; each is timed ``--repeat`` times and the best counts. Prints ms per
view, old and new, and the speed-up, and asserts that both gave the same detections
(labels, boxes, scores, captions, masks) and left the random generator in
the same state. Rendering is not timed. The old colour measure is a BLAS product, which
threads: on a busy machine it slows down far more than the rest, so
OPENBLAS_NUM_THREADS=1 times the algorithms rather than the contention.

    python benchmarks/detector.py [--decisions 60] [--repeat 5] [--false-positive-rate 0.03]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skyvln_eval.agent import Perception, PerceptionConfig
from skyvln_eval.agent.base import episode_key, episode_seed
from skyvln_eval.agent.detectors import (
    Detection,
    SimulatedDetector,
)
from skyvln_eval.avdn import load_split
from skyvln_eval.frames import view_to_pose
from skyvln_eval.sensing import CameraImages, SensorConfig
from skyvln_eval.sim.sensors import SimulatedSensors
from skyvln_eval.worlds import WorldTile, load_world
from skyvln_eval.worlds.sample import ensure_sample

# The earlier algorithm lives with the test that compares with it; the checkout's root
# makes ``tests`` importable (this script's folder is first on sys.path when it runs).
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))
from tests.agent.detector_reference import ReferenceDetector

Episode = tuple[int, list[list[CameraImages]]]  # the detector's seed, its decisions' views


def render(decisions: int) -> list[Episode]:
    """The panoramas seen from the ground-truth views of val_seen's ANDH episodes."""
    data_dir = ensure_sample()
    perception = Perception(PerceptionConfig(), SimulatedDetector())
    worlds: dict[str, WorldTile] = {}
    episodes: list[Episode] = []
    left = decisions
    for episode in load_split(data_dir, "val_seen").episodes("andh"):
        if left <= 0:
            break
        world = worlds.get(episode.map_name)
        if world is None:
            world = worlds[episode.map_name] = load_world(
                data_dir, episode.map_name, episode.georef
            )
        views = []
        for corners in episode.gt_path_corners[:left]:
            pose = view_to_pose(corners, episode.georef)
            sensors = SimulatedSensors(world, pose.x_m, pose.y_m, pose.z_m, SensorConfig())
            views.append([view.images for view in perception.capture(sensors, pose)])
        left -= len(views)
        episodes.append((episode_seed(0, episode_key(episode.episode_id)), views))
    return episodes


def run(
    detector: Any, episodes: Sequence[Episode]
) -> tuple[float, list[list[Detection]], dict[str, Any]]:
    """Seconds spent detecting, the detections of every view, the generator's state."""
    found: list[list[Detection]] = []
    spent = 0.0
    for seed, decisions in episodes:
        detector.reset(seed)
        for views in decisions:
            for images in views:
                start = time.perf_counter()
                found.append(detector.detect(images))
                spent += time.perf_counter() - start
    rng = detector.rng if isinstance(detector, ReferenceDetector) else detector._rng
    return spent, found, dict(rng.bit_generator.state)


def same(old: list[list[Detection]], new: list[list[Detection]]) -> int:
    """The number of detections, after checking both lists detection by detection."""
    assert len(old) == len(new)
    count = 0
    for a_view, b_view in zip(old, new, strict=True):
        assert len(a_view) == len(b_view)
        for a, b in zip(a_view, b_view, strict=True):
            assert (a.label, a.box_px, a.score, a.caption) == (
                b.label,
                b.box_px,
                b.score,
                b.caption,
            )
            assert a.mask is not None and b.mask is not None and np.array_equal(a.mask, b.mask)
            count += 1
    return count


def best(repeat: int, passes: Sequence[Callable[[], float]]) -> list[float]:
    """Each pass's best time, the passes alternating so that load affects them alike."""
    times: list[list[float]] = [[] for _ in passes]
    for _ in range(repeat):
        for spent, one in zip(times, passes, strict=True):
            spent.append(one())
    return [min(t) for t in times]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--decisions", type=int, default=60, help="5 captures each")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--false-positive-rate", type=float, default=0.03)
    args = parser.parse_args()
    start = time.perf_counter()
    episodes = render(args.decisions)
    views = sum(len(v) for _, decisions in episodes for v in decisions)
    print(
        f"{len(episodes)} episodes, {views // 5} decisions, {views} captures "
        f"(rendered in {time.perf_counter() - start:.1f} s)"
    )
    old = ReferenceDetector(false_positive_rate=args.false_positive_rate)
    new = SimulatedDetector(false_positive_rate=args.false_positive_rate)
    _, old_found, old_state = run(old, episodes)
    _, new_found, new_state = run(new, episodes)
    detections = same(old_found, new_found)
    assert old_state == new_state, "the detectors drew different random numbers"
    print(f"{detections} detections, identical; random generator in the same state")
    old_s, new_s = best(args.repeat, [lambda: run(old, episodes)[0], lambda: run(new, episodes)[0]])
    print(f"old algorithm: {old_s / views * 1e3:7.3f} ms per view")
    print(f"SimulatedDetector: {new_s / views * 1e3:7.3f} ms per view")
    print(f"speed-up: {old_s / new_s:.2f}x (best of {args.repeat})")


if __name__ == "__main__":
    main()
