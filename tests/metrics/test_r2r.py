"""R2R-family metrics: hand-computed cases, brute-force DTW and property checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyvln_eval.metrics import MetricConventions, dtw_distance, score_results, summarise
from tests.metrics.helpers import result, square


def brute_force_dtw(p: np.ndarray, r: np.ndarray) -> float:
    """Minimum cost over every monotone warping path, enumerated explicitly."""
    best = math.inf

    def walk(i: int, j: int, cost: float) -> None:
        nonlocal best
        cost += float(np.linalg.norm(p[i] - r[j]))
        if i == len(p) - 1 and j == len(r) - 1:
            best = min(best, cost)
            return
        if i + 1 < len(p):
            walk(i + 1, j, cost)
        if j + 1 < len(r):
            walk(i, j + 1, cost)
        if i + 1 < len(p) and j + 1 < len(r):
            walk(i + 1, j + 1, cost)

    walk(0, 0, 0.0)
    return best


def test_dtw_matches_brute_force_on_random_paths() -> None:
    rng = np.random.default_rng(7)
    pairs = []
    for _ in range(60):
        k, n = rng.integers(1, 6, size=2)
        dim = int(rng.integers(2, 4))
        pairs.append((rng.normal(0, 30, (k, dim)), rng.normal(0, 30, (n, dim))))
    for dim in (2, 3):
        chosen = [(p, r) for p, r in pairs if p.shape[1] == dim]
        kmax = max(len(p) for p, _ in chosen)
        nmax = max(len(r) for _, r in chosen)
        pts = np.stack(
            [np.concatenate([p, np.repeat(p[-1:], kmax - len(p), 0)]) for p, _ in chosen]
        )
        ref = np.stack(
            [np.concatenate([r, np.repeat(r[-1:], nmax - len(r), 0)]) for _, r in chosen]
        )
        got = dtw_distance(
            pts, np.array([len(p) for p, _ in chosen]), ref, np.array([len(r) for _, r in chosen])
        )
        want = [brute_force_dtw(p, r) for p, r in chosen]
        np.testing.assert_allclose(got, want, rtol=1e-12)


def test_identical_paths_score_perfectly() -> None:
    path = [square(0, 0), square(30, 0), square(60, 10)]
    row = score_results([result(path, path)]).iloc[0]
    assert (row.r2r_sr, row.r2r_osr, row.ndtw, row.sdtw, row.cls) == (1.0, 1.0, 1.0, 1.0, 1.0)
    assert row.r2r_spl == pytest.approx(1.0)
    assert row.r2r_tl_m == pytest.approx(30.0 + math.hypot(30, 10))


def test_parallel_offset_path_hand_computed() -> None:
    # Reference 0 -> 100 m north; the agent flies the same 100 m, 10 m to the east.
    ref = [square(0, 0), square(100, 0)]
    path = [square(0, 10), square(100, 10)]
    row = score_results([result(path, ref)]).iloc[0]
    d_th = 20.0
    assert row.r2r_ne_m == pytest.approx(10.0)
    assert row.r2r_sr == 1.0
    assert row.r2r_spl == pytest.approx(1.0)
    assert row.ndtw == pytest.approx(math.exp(-20.0 / (2 * d_th)))  # DTW = 10 + 10
    coverage = math.exp(-10.0 / d_th)
    assert row.cls == pytest.approx(coverage * coverage)  # LS = PC when TL = L_R
    assert row.sdtw == pytest.approx(row.ndtw)


def test_threshold_strictness_and_3d_height() -> None:
    ref = [square(0, 0), square(100, 0)]
    path = [square(0, 0), square(100, 0, edge_m=80.0)]  # same centre, 20 m higher in 3-D
    two_d = score_results([result(path, ref)]).iloc[0]
    assert two_d.r2r_ne_m == pytest.approx(0.0, abs=1e-9)
    three_d = score_results([result(path, ref)], MetricConventions(distance="3d")).iloc[0]
    ne = three_d.r2r_ne_m
    assert ne == pytest.approx(20.0)
    strict = MetricConventions(distance="3d", threshold_m=float(ne))
    loose = MetricConventions(distance="3d", threshold_m=float(ne), strict_threshold=False)
    assert score_results([result(path, ref)], strict).r2r_sr[0] == 0.0
    assert score_results([result(path, ref)], loose).r2r_sr[0] == 1.0


def test_spl_uses_the_gt_path_length_and_is_zero_for_a_zero_length_reference() -> None:
    ref = [square(0, 0), square(0, 60), square(80, 60)]  # GT path 140 m, D_net 100 m
    path = [square(0, 0), square(80, 60)]  # flies the 100 m straight line
    row = score_results([result(path, ref)]).iloc[0]
    assert row.r2r_spl == pytest.approx(1.0)  # 140 / max(100, 140)
    assert row.spl == pytest.approx(1.0)  # official: D_net / max(L_pred, D_net)
    # A route that ends where it starts (a start view alone means no ground truth).
    still = score_results([result([square(0, 0)], [square(0, 0), square(0, 0)])]).iloc[0]
    assert still.r2r_sr == 1.0 and still.r2r_spl == 0.0


def test_an_episode_that_ended_in_error_has_no_path_fidelity_however_it_was_recorded() -> None:
    # An audit: an error row at its start view kept nDTW 0.024 and CLS 0.134, the same
    # error with no views (it raised) 0 and 0; an error that flew the route kept 0.39.
    ref = [square(0, 0), square(0, 60), square(0, 120)]
    rows = [
        result(ref, ref, "error", episode_id="e1"),  # flew it all, then its model failed
        result([square(0, 0)], ref, "error", episode_id="e2"),  # never answered
        result(np.zeros((0, 4, 2)), ref, "error", episode_id="e3"),  # raised at once
        result(ref, ref, episode_id="e4"),
    ]
    scores = score_results(rows).set_index("episode_id")
    assert (scores.loc[["e1", "e2", "e3"], ["ndtw", "cls", "sdtw"]] == 0.0).all().all()
    assert scores.loc["e4", "ndtw"] == scores.loc["e4", "cls"] == 1.0
    # Its distances still say where it went.
    assert scores.loc["e1", "r2r_ne_m"] == pytest.approx(0.0, abs=1e-9)
    assert scores.loc["e2", "r2r_ne_m"] == scores.loc["e3", "r2r_ne_m"] > 100.0


def test_conventions_are_validated() -> None:
    from skyvln_eval.errors import ConfigError

    with pytest.raises(ConfigError, match="threshold_m"):
        MetricConventions(threshold_m=math.nan)
    with pytest.raises(ConfigError, match="distance"):
        MetricConventions(distance="4d")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="success_iou"):
        MetricConventions(success_iou=0.5)
    c = MetricConventions(distance="3d", threshold_m=3.0)
    assert MetricConventions.from_dict(c.to_dict()) == c


view = st.builds(
    lambda n, e, edge: square(n, e, edge),
    st.floats(-300, 300),
    st.floats(-300, 300),
    st.sampled_from([0.0, 1e-6, 40.0, 150.0, 400.0]),  # zero-size views included
)


@settings(max_examples=60, deadline=None)
@given(
    episodes=st.lists(
        st.tuples(
            st.lists(view, min_size=0, max_size=6),
            st.lists(view, min_size=2, max_size=6),  # a ground truth: start and more
            st.sampled_from(["ok", "error"]),
            st.booleans(),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_every_metric_is_finite_and_spl_never_exceeds_one(episodes: list) -> None:
    results = []
    for k, (visited, gt, status, repeat_start) in enumerate(episodes):
        if repeat_start and visited:
            visited = [gt[0], *visited]
        if not visited:
            status = "error"
        v = np.stack(visited) if visited else np.zeros((0, 4, 2))
        results.append(result(v, np.stack(gt), status=status, episode_id=f"e{k}"))
    for conventions in (
        MetricConventions(),
        MetricConventions(distance="3d", strict_threshold=False),
    ):
        scores = score_results(results, conventions)
        numeric = scores.select_dtypes("number").drop(columns=["n_views", "n_gt_views"])
        core = numeric.loc[:, ~numeric.columns.isin(["min_clearance_m"])].astype(float)
        assert np.isfinite(core.dropna(axis=1, how="all").to_numpy()).all()
        for column in ("spl", "r2r_spl", "ndtw", "sdtw", "cls", "final_iou"):
            assert ((scores[column] >= 0) & (scores[column] <= 1 + 1e-12)).all(), column
        summary = summarise(scores, n_resamples=20, ci_unit="episode", warn_errors=False)
        assert np.isfinite(summary["mean"].to_numpy()).all()
        # Every interval is a number, but a bootstrap's without spread (over one episode,
        # or equal values): n/a, never [x, x].
        bootstrap = (summary.ci_method == "bootstrap").to_numpy()
        bounds = summary[["ci_low", "ci_high"]].to_numpy()
        none = np.isnan(bounds[:, 0])
        assert np.isnan(bounds[none]).all() and np.isfinite(bounds[~none]).all()
        assert bootstrap[none].all() and none[bootstrap & (summary.n < 2).to_numpy()].all()
        assert (bounds[bootstrap & ~none, 1] > bounds[bootstrap & ~none, 0]).all()
