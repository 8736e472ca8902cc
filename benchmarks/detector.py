"""Benchmark: the simulated detector on the 5 views of a decision, against the old algorithm.

Renders the panorama (4 headings and the view straight down, the agent's default) from
every ground-truth view of the ANDH episodes of the synthetic sample's val_seen split,
until ``--decisions`` decisions (5 captures each), then runs
:class:`~skyvln_eval.agent.detectors.SimulatedDetector` over them episode by episode (reset
with the episode's seed, as the agent does, so buildings met earlier in the episode are
remembered) and, as the baseline in the same process, the detector's algorithm as it was
before it was vectorised (a Python loop over every plain building: its pixels, its points
and medians one by one, a linear scan of the buildings met; kept here, not in the
package). Old and new passes alternate; each is timed ``--repeat`` times and the best
counts. Prints ms per view, old and new, and the speed-up, and asserts that both gave the
same detections (labels, boxes, scores, captions, masks) and left the random generator in
the same state. Rendering is not timed. The old colour measure is a BLAS product, which
threads: on a busy machine it slows down far more than the rest, so
OPENBLAS_NUM_THREADS=1 times the algorithms rather than the contention.

    PYTHONPATH=. python benchmarks/detector.py [--decisions 60] [--repeat 5]
                                               [--false-positive-rate 0.03]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from skyvln_eval.agent import Perception, PerceptionConfig
from skyvln_eval.agent.detectors import (
    _BUILDING_LABELS,
    _NAMED_COLOURS,
    Detection,
    SimulatedDetector,
    episode_seed,
)
from skyvln_eval.avdn import load_split
from skyvln_eval.frames import view_to_pose
from skyvln_eval.sensing import CameraImages, SemanticClass, SensorConfig
from skyvln_eval.sim.sensors import SimulatedSensors
from skyvln_eval.vocabulary import CATEGORY_LABELS
from skyvln_eval.worlds import WorldTile, load_world
from skyvln_eval.worlds.sample import ensure_sample


class OldDetector:
    """SimulatedDetector.detect as it was before it was vectorised (same rules, same draws)."""

    def __init__(self, false_positive_rate: float, seed: int = 0) -> None:
        self.miss_rate, self.false_positive_rate, self.confusion_rate = (
            0.1,
            false_positive_rate,
            0.05,
        )
        self.min_pixels, self.close_look_m, self.phantom_cell_m = 25, 70.0, 30.0
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.buildings: list[tuple[float, float, tuple[str, float] | None]] = []

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng([self.seed, seed])
        self.buildings = []

    def detect(self, images: CameraImages) -> list[Detection]:
        semantic, instance = images.semantic, images.instance
        assert semantic is not None and instance is not None
        ids, counts = np.unique(instance, return_counts=True)
        out = []
        for landmark_id, count in zip(ids.tolist(), counts.tolist(), strict=True):
            if landmark_id == 0 or count < self.min_pixels or self.rng.random() < self.miss_rate:
                continue
            category = images.instance_categories.get(landmark_id, "landmark")
            label = CATEGORY_LABELS.get(category, category.replace("_", " "))
            if self.rng.random() < self.confusion_rate:
                label = _BUILDING_LABELS[int(self.rng.integers(len(_BUILDING_LABELS)))]
            mask = instance == landmark_id
            visible = min(1.0, float(np.sqrt(count)) / 40.0)
            score = float(np.clip(0.45 + 0.5 * visible + self.rng.normal(0.0, 0.05), 0.05, 0.99))
            caption = old_caption(label, images.rgb[mask], semantic[mask])
            out.append(Detection(label, old_box_of(mask), score, caption, mask))
        return out + self.phantoms(images, semantic, instance)

    def phantoms(
        self, images: CameraImages, semantic: np.ndarray, instance: np.ndarray
    ) -> list[Detection]:
        if self.false_positive_rate <= 0.0:
            return []
        plain = ((semantic == SemanticClass.BUILDING) & (instance == 0)).astype(np.uint8)
        count, components, stats, _ = cv2.connectedComponentsWithStats(plain, connectivity=4)
        out = []
        finite = images.finite_depth()
        for component in range(1, count):
            x0, y0, w, h, area = (int(value) for value in stats[component])
            if area < self.min_pixels:
                continue
            window = (slice(y0, y0 + h), slice(x0, x0 + w))
            v, u = np.nonzero((components[window] == component) & finite[window])
            if len(u) < self.min_pixels:
                continue
            v, u = v + y0, u + x0
            step = max(1, len(u) // 200)
            points = images.points_enu(u[::step], v[::step])
            x, y = float(np.median(points[:, 0])), float(np.median(points[:, 1]))
            phantom = self.phantom_at(x, y)
            if phantom is None:
                continue
            camera = np.array([images.pose.x_m, images.pose.y_m, images.pose.z_m])
            if float(np.median(np.linalg.norm(points - camera, axis=1))) < self.close_look_m:
                continue
            if self.rng.random() < self.miss_rate:
                continue
            label, base = phantom
            score = float(np.clip(base + self.rng.normal(0.0, 0.05), 0.05, 0.99))
            mask = np.zeros(plain.shape, dtype=bool)
            mask[v, u] = True
            caption = old_caption(label, images.rgb[v, u], semantic[v, u])
            out.append(Detection(label, old_box_of(mask), score, caption, mask))
        return out

    def phantom_at(self, x_m: float, y_m: float) -> tuple[str, float] | None:
        for bx, by, known in self.buildings:
            if math.hypot(bx - x_m, by - y_m) <= self.phantom_cell_m:
                return known
        decision = None
        if self.rng.random() < self.false_positive_rate:
            label = _BUILDING_LABELS[int(self.rng.integers(len(_BUILDING_LABELS)))]
            decision = (label, float(self.rng.uniform(0.35, 0.7)))
        self.buildings.append((x_m, y_m, decision))
        return decision


def old_box_of(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


PALETTE = np.array(list(_NAMED_COLOURS.values()), dtype=np.float64)


def old_colour_name(rgb: np.ndarray) -> str:
    pixels = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    nearest = np.argmin(pixels @ (-2.0 * PALETTE.T) + (PALETTE**2).sum(axis=1), axis=1)
    return list(_NAMED_COLOURS)[int(np.bincount(nearest, minlength=len(PALETTE)).argmax())]


def old_caption(label: str, rgb: np.ndarray, semantic: np.ndarray) -> str:
    colour = old_colour_name(rgb)
    if np.mean(semantic == SemanticClass.BUILDING) >= 0.5:
        return f"a {label} with a {colour} roof"
    return f"a {colour} {label}"


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
        episodes.append((episode_seed(0, episode.episode_id), views))
    return episodes


def run(
    detector: Any, episodes: Sequence[Episode]
) -> tuple[float, list[list[Detection]], dict[str, Any]]:
    """Seconds spent detecting, the detections of every view, the generator's state."""
    found = []
    spent = 0.0
    for seed, decisions in episodes:
        detector.reset(seed)
        for views in decisions:
            for images in views:
                start = time.perf_counter()
                found.append(detector.detect(images))
                spent += time.perf_counter() - start
    rng = detector.rng if isinstance(detector, OldDetector) else detector._rng
    return spent, found, rng.bit_generator.state


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
    old = OldDetector(args.false_positive_rate)
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
