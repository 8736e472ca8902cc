"""Benchmark: score 100,000 synthetic episodes; bootstrap 10,000 resamples over 10,000.

Scoring: synthetic episodes (GT of 2-8 views, agent paths of 1-10 views, about a third
ending near the goal) are turned into ``EpisodeResult`` rows and scored with
``score_results`` (official AVDN + R2R family + cost / control columns). Baseline in the
same process: a plain per-episode loop in the style of the official evaluation (one
shapely IoU per visited view, Python DTW), timed on a subset and scaled per episode.

Bootstrap: ``bootstrap_ci`` with 10,000 resamples over 10,000 per-episode values, against
a plain loop drawing one resample at a time and ``scipy.stats.bootstrap`` (percentile).
Aims: scoring under 10 s, bootstrap under 2 s.

    PYTHONPATH=. python benchmarks/metrics.py [--episodes N] [--baseline N]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import shapely

from skyvln_eval.avdn import METERS_PER_DEGREE, view_from_pose
from skyvln_eval.metrics import EpisodeResult, bootstrap_ci, score_results

T = TypeVar("T")


def synthetic_views(rng: np.random.Generator, n: int) -> tuple[list, list]:
    """``n`` (visited, gt) pairs of view stacks on a 2 km map around (30, 40)."""
    visited, gts = [], []
    for _ in range(n):
        steps = int(rng.integers(2, 9))
        heading = rng.uniform(0, 360)
        centre = np.array([30.0, 40.0]) + rng.uniform(0, 0.01, 2)
        gt = []
        for _ in range(steps):
            gt.append(view_from_pose(centre, heading, rng.uniform(40, 400)))
            heading = (heading + rng.normal(0, 30)) % 360
            move = rng.uniform(20, 60) / METERS_PER_DEGREE
            centre = centre + move * np.array(
                [math.cos(math.radians(heading)), math.sin(math.radians(heading))]
            )
        gt_arr = np.stack(gt)
        k = int(rng.integers(1, 11))
        end = gt_arr[-1].mean(axis=0)
        if rng.random() < 0.35:
            end = end + rng.normal(0, 10, 2) / METERS_PER_DEGREE
        else:
            end = end + rng.normal(0, 150, 2) / METERS_PER_DEGREE
        start = gt_arr[0].mean(axis=0)
        path = [gt_arr[0]]
        for j in range(1, k):
            point = (
                start + (end - start) * j / max(1, k - 1) + rng.normal(0, 5, 2) / METERS_PER_DEGREE
            )
            path.append(view_from_pose(point, rng.uniform(0, 360), rng.uniform(40, 400)))
        visited.append(np.stack(path))
        gts.append(gt_arr)
    return visited, gts


def naive_score(visited: np.ndarray, gt: np.ndarray, threshold_m: float = 20.0) -> dict[str, float]:
    """One episode the simple way: shapely objects per view and a Python DTW."""
    goal = shapely.Polygon(gt[-1])
    ious = []
    for view in visited:
        poly = shapely.Polygon(view)
        inter = poly.intersection(goal).area
        hull = shapely.MultiPoint(np.concatenate([view, gt[-1]])).convex_hull.area
        ious.append(inter / hull if hull > 0 else 0.0)
    last = shapely.Polygon(visited[-1])
    success = ious[-1] >= 0.4 and last.contains(goal.centroid) and goal.contains(last.centroid)
    p = visited.mean(axis=1) * METERS_PER_DEGREE
    r = gt.mean(axis=1) * METERS_PER_DEGREE
    dtw = np.full((len(p) + 1, len(r) + 1), np.inf)
    dtw[0, 0] = 0.0
    for i in range(1, len(p) + 1):
        for j in range(1, len(r) + 1):
            cost = float(np.linalg.norm(p[i - 1] - r[j - 1]))
            dtw[i, j] = cost + min(dtw[i - 1, j], dtw[i, j - 1], dtw[i - 1, j - 1])
    return {"success": float(success), "oracle": float(max(ious) > 0.4),
            "ndtw": math.exp(-dtw[-1, -1] / (len(r) * threshold_m))}  # fmt: skip


def timed(fn: Callable[[], T]) -> tuple[T, float]:
    start = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=100_000)
    parser.add_argument("--baseline", type=int, default=2_000, help="episodes for the naive loop")
    parser.add_argument("--resamples", type=int, default=10_000)
    parser.add_argument("--bootstrap-n", type=int, default=10_000)
    args = parser.parse_args()
    n_boot = args.resamples
    rng = np.random.default_rng(0)

    (visited, gts), t_gen = timed(lambda: synthetic_views(rng, args.episodes))
    print(f"generated {args.episodes:,} synthetic episodes in {t_gen:.1f} s (not timed below)")

    def build() -> list[EpisodeResult]:
        return [
            EpisodeResult(
                episode_id=f"e{k}",
                split="val_unseen",
                mode="andh",
                system="bench",
                status="ok",
                visited_views=v,
                gt_path_corners=g,
            )
            for k, (v, g) in enumerate(zip(visited, gts, strict=True))
        ]

    results, t_build = timed(build)
    scores, t_score = timed(lambda: score_results(results))
    m = args.baseline
    naive, t_naive = timed(
        lambda: [naive_score(v, g) for v, g in zip(visited[:m], gts[:m], strict=True)]
    )
    agree = all(
        n["success"] == s
        and n["oracle"] == o
        and math.isclose(n["ndtw"], d, rel_tol=1e-9, abs_tol=1e-12)
        for n, s, o, d in zip(
            naive, scores.success[:m], scores.oracle_success[:m], scores.ndtw[:m], strict=True
        )
    )
    naive_total = t_naive / m * args.episodes
    views = np.mean([len(v) for v in visited])
    gt_views = np.mean([len(g) for g in gts])
    print(f"\nscoring {args.episodes:,} episodes ({views:.1f} views, {gt_views:.1f} GT views)")
    line("EpisodeResult construction + validation", t_build)
    line("score_results (official + R2R + cost)", t_score, "aim < 10 s for 100,000 episodes")
    line(f"naive per-episode loop, {m:,} episodes", t_naive, f"-> {naive_total:.1f} s scaled")
    print(f"  ratio naive / score_results: {naive_total / t_score:.1f}x (agree on subset: {agree})")
    if not agree:  # a faster scorer that scores otherwise is no result
        raise SystemExit("score_results and the naive per-episode scorer disagree")
    sr, osr = scores.success.mean() * 100, scores.oracle_success.mean() * 100
    print(f"  SR {sr:.1f} %, OSR {osr:.1f} %, SPL {scores.spl.mean() * 100:.1f} %")

    values = scores.success.to_numpy()[: args.bootstrap_n]
    n = len(values)
    ci, t_boot = timed(lambda: bootstrap_ci(values, args.resamples, seed=0))
    loop_rng = np.random.default_rng(0)
    _, t_loop = timed(lambda: [values[loop_rng.integers(0, n, n)].mean() for _ in range(n_boot)])
    from scipy import stats

    _, t_scipy = timed(
        lambda: stats.bootstrap(
            (values,), np.mean, n_resamples=n_boot, method="percentile", random_state=0
        )
    )
    print(f"\nbootstrap, {n_boot:,} resamples over {n:,} episodes")
    interval = f"SR {ci.mean * 100:.2f} % [{ci.low * 100:.2f}, {ci.high * 100:.2f}]"
    line("bootstrap_ci", t_boot, f"aim < 2 s for 10,000 resamples of 10,000   {interval}")
    line("one resample at a time", t_loop, f"ratio to bootstrap_ci {t_loop / t_boot:.2f}x")
    line("scipy.stats.bootstrap", t_scipy, f"ratio to bootstrap_ci {t_scipy / t_boot:.2f}x")


def line(what: str, seconds: float, note: str = "") -> None:
    print(f"  {what:<44} {seconds:7.2f} s   {note}")


if __name__ == "__main__":
    main()
