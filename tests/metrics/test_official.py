"""Official AVDN metrics on hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from skyvln_eval.avdn import METERS_PER_DEGREE, hull_iou, view_from_pose
from skyvln_eval.errors import MetricInputError, NoGroundTruthError, ResultRecordError
from skyvln_eval.metrics import MetricConventions, score_results, sparse_hull_iou
from skyvln_eval.metrics.official import official_success
from tests.metrics.helpers import LAT0, LNG0, box, result, square

U = 2.0**-10  # a dyadic degree step: areas and ratios below are exact in floating point


def standard_iou(a: np.ndarray, b: np.ndarray) -> float:
    """The usual intersection over union (test reference only)."""
    pa, pb = shapely.Polygon(a), shapely.Polygon(b)
    return float(pa.intersection(pb).area / pa.union(pb).area)


def test_hull_iou_equals_standard_iou_when_the_hull_is_the_union() -> None:
    # Unit squares half-overlapping along one axis: intersection 1/2, union = hull = 3/2.
    a = box(LAT0, LAT0 + 2 * U, LNG0, LNG0 + 2 * U)
    b = box(LAT0, LAT0 + 2 * U, LNG0 + U, LNG0 + 3 * U)
    assert hull_iou(a, b) == pytest.approx(1 / 3, abs=1e-12)
    assert standard_iou(a, b) == pytest.approx(1 / 3, abs=1e-12)


def test_hull_iou_is_below_standard_iou_when_the_hull_exceeds_the_union() -> None:
    # Diagonal offset: intersection 1/4, union 7/4, hull 2 (the 1.5 x 1.5 box less two
    # corner triangles of 1/8 each).
    a = box(LAT0, LAT0 + 2 * U, LNG0, LNG0 + 2 * U)
    b = box(LAT0 + U, LAT0 + 3 * U, LNG0 + U, LNG0 + 3 * U)
    assert standard_iou(a, b) == pytest.approx(1 / 7, abs=1e-12)
    assert hull_iou(a, b) == pytest.approx(1 / 8, abs=1e-12)
    assert sparse_hull_iou(a[None], b[None])[0] == pytest.approx(1 / 8, abs=1e-12)


def test_sparse_hull_iou_matches_dense_and_is_zero_for_far_views() -> None:
    rng = np.random.default_rng(3)
    a = np.stack([square(*rng.uniform(-80, 80, 2), rng.uniform(40, 120)) for _ in range(300)])
    b = np.stack([square(*rng.uniform(-80, 80, 2), rng.uniform(40, 120)) for _ in range(300)])
    dense = hull_iou(a, b)
    assert (dense == 0).any() and (dense > 0).any()
    sparse = sparse_hull_iou(a, b)
    np.testing.assert_array_equal(sparse == 0, dense == 0)
    np.testing.assert_allclose(sparse, dense, rtol=0, atol=1e-12)


def turned(north_m: float, east_m: float, edge_m: float, heading_deg: float) -> np.ndarray:
    """A view centred ``north_m`` / ``east_m`` from (LAT0, LNG0) facing ``heading_deg``."""
    centre = [LAT0 + north_m / METERS_PER_DEGREE, LNG0 + east_m / METERS_PER_DEGREE]
    return view_from_pose(centre, heading_deg, edge_m)


def test_the_numpy_intersection_agrees_with_shapely_on_touching_nested_and_turned_views() -> None:
    # Pairs where corners sit exactly on edges and edges overlap: the cases where a
    # rounding slip would drop a vertex of the intersection.
    cases = []
    for heading in (0.0, 10.0, 45.0, 133.7):
        a = turned(0, 0, 100, heading)
        for dx, dy, turn, edge in [
            (0, 0, 0, 100),  # identical
            (100, 0, 0, 100),  # sharing an edge: IoU 0
            (50, 0, 0, 100),  # half overlap
            (0, 0, 45, 100),  # turned by 45 degrees about the same centre
            (25, 25, 0, 50),  # nested, touching two edges
            (100, 100, 0, 100),  # touching at a corner
            (30, 0, 0, 40),  # nested, touching one edge
        ]:
            h = math.radians(heading)
            b = turned(dx * math.cos(h) - dy * math.sin(h), dx * math.sin(h) + dy * math.cos(h),
                       edge, heading + turn)  # fmt: skip
            cases.append((a, b))
    a, b = np.stack([c[0] for c in cases]), np.stack([c[1] for c in cases])
    np.testing.assert_allclose(sparse_hull_iou(a, b), hull_iou(a, b), rtol=0, atol=1e-12)


def test_iou_values_at_the_threshold_or_from_odd_corner_orders_are_the_official_ones() -> None:
    p, g = iou_exactly_04()
    bowtie = p[[1, 0, 3, 2]]  # not a convex quad in corner order: shapely decides
    got = sparse_hull_iou(np.stack([p, bowtie]), np.stack([g, g]))
    assert got[0] == 0.4  # exactly, so success (>= 0.4) and oracle (> 0.4) are AVDN.md's
    assert got[1] == hull_iou(bowtie, g)


def iou_exactly_04() -> tuple[np.ndarray, np.ndarray]:
    """G a 5U square, P a 2U x 5U band through its middle: hull-IoU exactly 0.4."""
    g = box(LAT0, LAT0 + 5 * U, LNG0, LNG0 + 5 * U)
    p = box(LAT0 + 1.5 * U, LAT0 + 3.5 * U, LNG0, LNG0 + 5 * U)
    assert hull_iou(p, g) == 0.4
    return p, g


def test_success_at_iou_exactly_04_but_oracle_success_needs_more() -> None:
    p, g = iou_exactly_04()
    start = box(LAT0 + 10 * U, LAT0 + 15 * U, LNG0, LNG0 + 5 * U)  # disjoint from G
    scores = score_results([result([start, p], [start, g])])
    assert scores.final_iou[0] == 0.4
    assert scores.success[0] == 1.0  # IoU >= 0.4 and both centres strictly inside
    assert scores.oracle_success[0] == 0.0  # oracle needs IoU > 0.4 (strict)


def test_centre_on_the_boundary_is_not_inside() -> None:
    g = box(LAT0, LAT0 + 4 * U, LNG0, LNG0 + 4 * U)
    on_edge = box(LAT0, LAT0 + 4 * U, LNG0 + 2 * U, LNG0 + 6 * U)  # centre on G's east edge
    inside = box(LAT0, LAT0 + 4 * U, LNG0 + 1.75 * U, LNG0 + 5.75 * U)
    iou = np.array([0.5, 0.5])  # the IoU test is passed; only the centre checks decide
    got = official_success(np.stack([on_edge, inside]), np.stack([g, g]), iou)
    assert got.tolist() == [False, True]
    # and each direction is checked: G's centre on P's edge fails too
    assert not official_success(g[None], on_edge[None], np.array([0.5]))[0]


def test_spl_gp_and_lengths_on_a_detour() -> None:
    g0, g1 = square(0, 0), square(100, 0)
    mid = square(50, 0)
    detour = square(0, 100)
    scores = score_results([result([g0, detour, g1], [g0, mid, g1])])
    d_net = 100.0
    l_pred = 100.0 + 100.0 * math.sqrt(2.0)
    assert scores.d_net_m[0] == pytest.approx(d_net)
    assert scores.path_length_m[0] == pytest.approx(l_pred)
    assert scores.gt_length_m[0] == pytest.approx(100.0)
    assert scores.success[0] == 1.0
    assert scores.spl[0] == pytest.approx(d_net / l_pred)
    assert scores.ne_m[0] == pytest.approx(0.0, abs=1e-9)
    assert scores.gp_m[0] == pytest.approx(100.0)
    assert scores.oracle_gp_m[0] == pytest.approx(100.0)


def test_gp_may_be_negative_and_legacy_gp_uses_the_second_last_view() -> None:
    g0, mid, g1 = square(0, 0), square(60, 0), square(100, 0)
    away = square(-50, 0)
    visited = [g0, away]
    scores = score_results([result(visited, [g0, mid, g1])])
    assert scores.ne_m[0] == pytest.approx(150.0)
    assert scores.gp_m[0] == pytest.approx(-50.0)
    assert scores.oracle_gp_m[0] == pytest.approx(0.0, abs=1e-9)  # the start is the closest
    legacy = score_results([result(visited, [g0, mid, g1])], MetricConventions(legacy_gp=True))
    assert legacy.gp_m[0] == pytest.approx(100.0 - 110.0)  # distance to G[N-2] is 110 m


def test_d_net_zero_gives_spl_zero_even_on_success() -> None:
    g0 = square(0, 0)
    scores = score_results(
        [result([g0], [g0, g0]), result([g0], [g0, square(50, 0), g0], episode_id="b")]
    )
    assert scores.success.tolist() == [1.0, 1.0]
    assert scores.d_net_m.tolist() == [0.0, 0.0]
    assert scores.spl.tolist() == [0.0, 0.0]


def test_spl_denominator_floor_and_never_above_one() -> None:
    g0, g1 = square(0, 0), square(0.001, 0)  # 1 mm apart: the 0.01 m floor applies
    scores = score_results([result([g0, g1], [g0, g1])])
    assert scores.spl[0] == pytest.approx(0.001 / 0.01)
    assert scores.spl[0] <= 1.0


def test_empty_failed_path_stays_at_the_start_and_never_succeeds() -> None:
    g0, g1 = square(0, 0), square(100, 0)
    scores = score_results([result(np.zeros((0, 4, 2)), [g0, g1], status="error", error="boom")])
    row = scores.iloc[0]
    assert row.n_views == 0
    assert (row.success, row.oracle_success, row.spl) == (0.0, 0.0, 0.0)
    assert row.ne_m == pytest.approx(100.0)
    assert row.gp_m == pytest.approx(0.0, abs=1e-9)
    assert row.path_length_m == 0.0
    assert (row.ndtw, row.cls, row.r2r_tl_m) == (0.0, 0.0, 0.0)


def test_failed_episode_at_the_goal_is_not_a_success() -> None:
    g0, g1 = square(0, 0), square(100, 0)
    scores = score_results([result([g0, g1], [g0, g1], status="error")])
    assert scores.success[0] == 0.0 and scores.oracle_success[0] == 0.0 and scores.spl[0] == 0.0
    assert scores.ne_m[0] == pytest.approx(0.0, abs=1e-9)  # distances still describe the path


def test_degenerate_zero_area_views_score_zero_iou() -> None:
    point = np.repeat(square(0, 0).mean(axis=0, keepdims=True), 4, axis=0)
    scores = score_results([result([point], [square(0, 0), square(10, 0)])])
    assert scores.final_iou[0] == 0.0 and scores.success[0] == 0.0


def test_nan_and_inf_inputs_are_refused_with_the_field() -> None:
    views = np.stack([square(0, 0), square(10, 0)])
    views[1, 2, 0] = np.nan
    with pytest.raises(ResultRecordError, match=r"visited_views\[1\]\[2\]\[0\].*non-finite"):
        result(views, [square(0, 0)])
    gt = square(0, 0)[None].copy()
    gt[0, 0, 1] = np.inf
    with pytest.raises(ResultRecordError, match=r"gt_path_corners\[0\]\[0\]\[1\]"):
        result([square(0, 0)], gt)


def test_an_ok_episode_needs_its_start_view_and_scoring_needs_input() -> None:
    with pytest.raises(ResultRecordError, match="start view"):
        result(np.zeros((0, 4, 2)), [square(0, 0)])
    with pytest.raises(MetricInputError, match="no episode results"):
        score_results([])
    with pytest.raises(ResultRecordError, match="duplicate"):
        score_results([result([square(0, 0)], [square(0, 0)])] * 2)


def test_the_iou_upper_bound_holds_and_oracle_success_matches_a_dense_computation() -> None:
    from skyvln_eval.metrics.view_overlap import hull_iou_upper_bound

    rng = np.random.default_rng(11)
    a = np.stack([square(*rng.uniform(-60, 60, 2), rng.uniform(40, 200)) for _ in range(400)])
    b = np.stack([square(*rng.uniform(-60, 60, 2), rng.uniform(40, 200)) for _ in range(400)])
    p, g = iou_exactly_04()
    a, b = np.concatenate([a, [p, g, p[[1, 0, 3, 2]]]]), np.concatenate([b, [g, g, g]])
    assert (hull_iou_upper_bound(a, b) >= hull_iou(a, b) * (1 - 1e-9)).all()
    # Oracle success of random paths equals the dense definition (every view's IoU).
    results, dense = [], []
    for k in range(150):
        gt = np.stack([square(0, 0), square(*rng.uniform(-80, 80, 2), rng.uniform(40, 200))])
        path = np.stack([square(*rng.uniform(-80, 80, 2), rng.uniform(40, 200)) for _ in range(4)])
        results.append(result(path, gt, episode_id=f"e{k}"))
        dense.append(float((hull_iou(path, np.repeat(gt[-1:], 4, axis=0)) > 0.4).any()))
    scores = score_results(results)
    assert scores.oracle_success.tolist() == dense
    assert 0 < sum(dense) < len(dense)


def test_a_result_without_ground_truth_is_refused_not_scored_as_a_failure() -> None:
    g0, g1 = square(0, 0), square(100, 0)
    withheld = result([g0, g1], [g0], episode_id="w")  # the start view alone
    assert not withheld.has_ground_truth
    with pytest.raises(NoGroundTruthError, match=r"no ground truth for 1 episode\(s\) \(w"):
        score_results([result([g0, g1], [g0, g1]), withheld])


def test_lengths_and_final_iou_are_the_spec_operations_to_the_last_bit() -> None:
    """L_pred is the sum of steps, each the norm of a degree difference times 111,300
    (not a difference of metres of absolute positions, which cancels digits), and the
    final IoU column is the shapely definition's value, not the fast path's."""
    rng = np.random.default_rng(7)
    results, paths = [], []
    for i in range(40):
        centres = [(rng.uniform(-300, 300), rng.uniform(-300, 300)) for _ in range(5)]
        path = [square(n, e, edge_m=rng.uniform(30, 80)) for n, e in centres]
        gt = [path[0], square(*centres[-1])]
        results.append(result(path, gt, episode_id=f"1913__{i}_1"))
        paths.append((path, gt))
    scores = score_results(results)
    for row, (path, gt) in enumerate(paths):
        c = [view.mean(axis=0) for view in path]
        steps = [
            float(np.linalg.norm(c[k + 1] - c[k])) * METERS_PER_DEGREE for k in range(len(c) - 1)
        ]
        # Summation order is numpy's (SIMD partial sums): equal to a few ulps of the total.
        assert scores.path_length_m[row] == pytest.approx(math.fsum(steps), rel=1e-15, abs=0)
        assert scores.final_iou[row] == hull_iou(path[-1], gt[-1])
