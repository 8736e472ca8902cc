"""Figures render headless, say what they should, and are byte-identical for equal input."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pytest

from skyvln_eval.avdn import MapGeoref, view_from_pose
from skyvln_eval.errors import DataError, MetricInputError
from skyvln_eval.metrics import MetricConventions, score_results
from skyvln_eval.reports import (
    control_figure,
    ne_distribution_figure,
    save_figure,
    sr_vs_threshold_figure,
    success_rate_curve,
    trajectory_figure,
)
from skyvln_eval.reports.trajectory_figure import trajectory_labels
from skyvln_eval.worlds import WorldTile
from tests.conftest import modules_loaded_by
from tests.metrics.helpers import result, square
from tests.metrics.test_safety_and_cost import control_log

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def two_controller_log() -> pd.DataFrame:
    logs = [
        control_log("nmpc", "static", offset_m=0.1),
        control_log("pid", "static", offset_m=0.8),
        control_log("nmpc", "dynamic", offset_m=0.2),
        control_log("pid", "dynamic", offset_m=1.5),
    ]
    return pd.concat(logs, ignore_index=True)


def test_control_figure_layout_lines_and_determinism(tmp_path: Path) -> None:
    log = two_controller_log()
    figure = control_figure(log, "dynamic")
    axes = figure.get_axes()
    assert len(axes) == 13
    clearance = axes[12]
    assert clearance.get_title().startswith("keep-out clearance (below 0")
    legend = [t.get_text() for t in clearance.get_legend().get_texts()]
    dynamic = log[log.scenario == "dynamic"]
    hits = [int(dynamic[dynamic.controller == c].collision.sum()) for c in ("nmpc", "pid")]
    assert legend == [f"nmpc: {hits[0]} collision step(s)", f"pid: {hits[1]} collision step(s)"]
    static = control_figure(log, "static").get_axes()[12]
    assert static.get_title() == "keep-out clearance: no obstacles in this scenario"
    titles = [ax.get_title() for ax in axes]
    assert titles[:3] == ["x position", "y position", "z position"]
    assert titles[3:6] == ["x error", "y error", "z error"]
    assert titles[6:9] == [
        "roll angle (dotted: command)",
        "pitch angle (dotted: command)",
        "yaw angle",
    ]
    assert titles[9:12] == [
        "roll minus command",
        "pitch minus command",
        "yaw error\n(the plant's heading loop, under every controller)",
    ]
    assert "not a like-for-like" not in figure.get_suptitle()  # one reference
    labels = [line.get_label() for line in axes[0].get_lines()]
    assert labels == ["reference", "nmpc", "pid"]  # shared reference drawn once
    roll_labels = [line.get_label() for line in axes[6].get_lines()]
    assert roll_labels == ["nmpc", "nmpc command", "pid", "pid command"]
    y_error = axes[4].get_lines()
    np.testing.assert_allclose(y_error[0].get_ydata(), 0.2)  # nmpc flies 0.2 m to the side
    for fmt in ("png", "pdf", "svg"):
        first = save_figure(control_figure(log, "static"), tmp_path / f"a.{fmt}").read_bytes()
        again = save_figure(control_figure(log, "static"), tmp_path / f"b.{fmt}").read_bytes()
        assert first == again, fmt
    with pytest.raises(DataError, match="choose one"):
        control_figure(log)
    # Controllers that flew different routes (dynamics runs: each agent chose its own):
    # drawn, and the title says the comparison is not like for like.
    apart = log.assign(ref_y_m=np.where(log.controller == "pid", log.ref_y_m + 5.0, log.ref_y_m))
    assert "not a like-for-like comparison" in control_figure(apart, "static").get_suptitle()
    # The same route at another pace (the paper's route: a segment starts on arrival).
    later = log.assign(t_s=np.where(log.controller == "pid", log.t_s * 1.1, log.t_s))
    assert "not a like-for-like" not in control_figure(later, "static").get_suptitle()
    # Two episodes of one controller would interleave in time: refused, not drawn.
    episodes = pd.concat(
        [control_log("nmpc", "static").assign(episode_id=e) for e in ("e1", "e2")],
        ignore_index=True,
    )
    with pytest.raises(DataError, match=r"2 episodes of controller 'nmpc'.*one episode's"):
        control_figure(episodes, "static")


def test_yaw_is_drawn_unwrapped() -> None:
    log = control_log("nmpc", "static")
    turning = np.linspace(3.0, 3.4, len(log))  # through +180 degrees
    wrapped = (turning + np.pi) % (2 * np.pi) - np.pi
    log = log.assign(yaw_rad=wrapped, ref_yaw_rad=wrapped)
    yaw = control_figure(log, "static").get_axes()[8].get_lines()
    assert all(np.all(np.diff(line.get_ydata()) > 0) for line in yaw)  # no jump of -360


def test_success_rate_curve_hand_computed() -> None:
    ne = np.array([0.0, 5.0, 10.0, 20.0])
    thresholds = np.array([0.0, 5.0, 15.0, 25.0])
    np.testing.assert_array_equal(success_rate_curve(ne, thresholds, strict=True), [0, 25, 75, 100])
    np.testing.assert_array_equal(
        success_rate_curve(ne, thresholds, strict=False), [25, 50, 75, 100]
    )


def test_navigation_figures_render(tmp_path: Path) -> None:
    g = [square(0, 0), square(100, 0)]
    results = [
        result([g[0], square(100 + k, 0)], g, episode_id=f"e{k}", system=s)
        for k in range(5)
        for s in ("A", "B")
    ]
    scores = score_results(results)
    figure = sr_vs_threshold_figure(scores, MetricConventions(), max_threshold_m=10.0)
    lines = figure.get_axes()[0].get_lines()
    assert [line.get_label() for line in lines[:2]] == ["A (n=5)", "B (n=5)"]
    ydata = np.asarray(lines[0].get_ydata())
    assert ydata[0] == pytest.approx(0.0) and ydata[-1] == pytest.approx(100.0)  # NE = 0..4 m
    assert ydata[np.searchsorted(np.linspace(0, 10, 401), 2.5)] == pytest.approx(60.0)
    assert save_figure(figure, tmp_path / "sr.png").stat().st_size > 0
    assert save_figure(ne_distribution_figure(scores), tmp_path / "ne.pdf").stat().st_size > 0


def test_trajectory_over_a_map_tile(tmp_path: Path) -> None:
    georef = MapGeoref((30.0, 40.0), (30.01, 40.01), 1e-5, 1e-5)
    bgr = np.zeros((1000, 1000, 3), np.uint8)
    bgr[:, :, 1] = 120
    tile = WorldTile(map_name="1913", georef=georef, bgr=bgr)
    gt = np.stack([view_from_pose((30.004 + 0.0004 * k, 40.005), 0.0, 100.0) for k in range(4)])
    figure = trajectory_figure(tile, gt, gt + 0.0001, title="demo")
    ax = figure.get_axes()[0]
    assert ax.get_title() == "demo"
    x0, x1 = ax.get_xlim()
    centre_px = georef.gps_to_pixel_float(gt.mean(axis=1))
    assert x0 < centre_px[:, 0].min() and centre_px[:, 0].max() < x1  # the views are in frame
    a = save_figure(figure, tmp_path / "t1.png").read_bytes()
    b = save_figure(
        trajectory_figure(tile, gt, gt + 0.0001, title="demo"), tmp_path / "t2.png"
    ).read_bytes()
    assert a == b


def test_figures_show_as_png_in_jupyter() -> None:
    # IPython displays an object with _repr_png_ as an image whatever matplotlib backend is
    # active (a bare Figure showed as '<Figure size 1200x1200 with 13 Axes>' under Agg).
    from IPython.core.formatters import PNGFormatter

    figure = control_figure(two_controller_log(), "static")
    png = PNGFormatter()(figure)
    assert isinstance(png, bytes) and png.startswith(b"\x89PNG\r\n\x1a\n")
    width, height = struct.unpack(">II", png[16:24])  # the IHDR chunk: the figure's pixels
    assert (width, height) == (1200, 1200)


def test_matplotlib_is_loaded_by_the_first_figure_not_by_the_command_line() -> None:
    # Every worker process of a command-line run imports the command line again (spawn
    # re-runs the console script): matplotlib there would cost each one ~0.5 s for nothing.
    assert modules_loaded_by("skyvln_eval.cli", ("matplotlib",)) == []
    assert modules_loaded_by("skyvln_eval.reports", ("matplotlib",)) == []


def test_the_sr_curve_reads_the_scores_sr() -> None:
    # A degraded episode is scored on its views (its success counts); an error one counts
    # as a failure, as in the scores' SR (and the tables'): at the conventions' threshold
    # the curve reads the scores' SR@d, and the legend says how the error was counted.
    g = [square(0, 0), square(100, 0)]
    statuses = ["ok", "degraded", "error", "ok"]
    results = [
        result([g[0], square(100 + k, 0)], g, episode_id=f"e{k}", status=status)
        for k, status in enumerate(statuses)
    ]
    scores = score_results(results)
    conventions = MetricConventions()
    figure = sr_vs_threshold_figure(scores, conventions, max_threshold_m=100.0)
    curve = figure.get_axes()[0].get_lines()[0]
    thresholds, rates = curve.get_data()
    at = int(np.searchsorted(np.asarray(thresholds), conventions.threshold_m))
    assert np.asarray(rates)[at] == pytest.approx(100.0 * scores["r2r_sr"].mean()) == 75.0
    assert curve.get_label() == "agent (n=4, 1 degraded, 1 error counted as a failure)"


def _statuses_and_a_reference() -> pd.DataFrame:
    """'dead': 4 errors; 'flaky': 2 ok, 1 degraded, 1 error 900 m off (NE 0..2 m else);
    'truth': flown by the ground-truth oracle."""
    g = [square(0, 0), square(100, 0)]
    rows = [result([g[0], g[1]], g, episode_id=f"d{k}", system="dead", status="error")
            for k in range(4)]  # fmt: skip
    for k, status in enumerate(("ok", "degraded", "ok", "error")):
        end = square(1000, 0) if status == "error" else square(100 + k, 0)
        rows.append(result([g[0], end], g, episode_id=f"f{k}", system="flaky", status=status))
    rows += [
        result([g[0], g[1]], g, episode_id=f"t{k}", system="truth", extra={"oracle": True})
        for k in range(2)
    ]
    return score_results(rows)


def _legend(figure: Figure) -> list[str]:
    return [t.get_text() for t in figure.get_axes()[0].get_legend().get_texts()]


def test_error_episodes_are_not_drawn_as_results_and_references_are_named() -> None:
    scores = _statuses_and_a_reference()
    sr = sr_vs_threshold_figure(scores, MetricConventions(), max_threshold_m=100.0)
    assert _legend(sr) == [
        "dead (4 of 4 episodes error: not drawn)",
        "flaky (n=4, 1 degraded, 1 error counted as a failure)",
        "truth, reference: ground-truth oracle (n=2)",
        "d_th = 20 m",
    ]
    lines = sr.get_axes()[0].get_lines()
    assert len(lines[0].get_xdata()) == 0  # 'dead': a name in the legend, no line
    assert np.asarray(lines[1].get_ydata())[-1] == pytest.approx(75.0)  # the error failed
    assert lines[2].get_linestyle() == "-."  # the reference, apart from the agents
    ne = ne_distribution_figure(scores)
    assert _legend(ne) == [
        "dead (4 of 4 episodes error: not drawn)",
        "flaky (n=4, 1 degraded, 1 error at where it stopped; median 1.5 m)",
        "truth, reference: ground-truth oracle (n=2; median 0.0 m)",
    ]
    # The error episode counts at where it stopped, 900 m away, as in the tables' NE.
    assert ne.get_axes()[0].get_xlim()[1] > 800.0


def test_a_trajectory_of_an_error_episode_says_so_in_its_title(tmp_path: Path) -> None:
    g = [square(0, 0), square(100, 0)]
    error = "LLMError: request refused (HTTP 400: bad)\nTraceback (most recent call last):\n..."
    failed = result([g[0], g[1]], g, status="error", error=error, system="S")
    assert trajectory_labels(failed) == (
        "S: 1913__0_1 — error: LLMError: request refused (HTTP 400: bad)",
        "agent, until the error",
    )
    long = result([g[0]], g, status="error", error="x" * 200, system="S")
    assert trajectory_labels(long)[0] == f"S: 1913__0_1 — error: {'x' * 77}..."
    degraded = result([g[0], g[1]], g, status="degraded", system="S")
    assert trajectory_labels(degraded) == ("S: 1913__0_1 — degraded", "agent")
    oracle = result([g[0], g[1]], g, system="truth", extra={"oracle": True})
    assert trajectory_labels(oracle) == ("truth: 1913__0_1", "ground-truth oracle (reference)")
    # Drawn: the title and the flown views' legend entry are those.
    georef = MapGeoref((30.0, 40.0), (30.01, 40.01), 1e-5, 1e-5)
    tile = WorldTile(map_name="1913", georef=georef, bgr=np.zeros((1000, 1000, 3), np.uint8))
    title, flown = trajectory_labels(failed)
    figure = trajectory_figure(tile, failed.gt_path_corners, failed.visited_views, title,
                               agent_label=flown)  # fmt: skip
    assert figure.get_axes()[0].get_title() == title
    assert flown in _legend(figure)


def test_the_sr_curve_says_how_crashed_flights_were_scored() -> None:
    from skyvln_eval.metrics import summarise_control
    from tests.metrics.test_safety_and_cost import control_log

    g = [square(0, 0), square(100, 0)]
    crashed = summarise_control(control_log("pid", "dynamic"))
    results = [result([g[0], square(100, 0)], g, episode_id="c", control=crashed)]
    for conventions, said in (
        (MetricConventions(), "1 crashed (failures)"),
        (MetricConventions(collision_fails=False), "1 crashed (scored on their views)"),
    ):
        figure = sr_vs_threshold_figure(score_results(results, conventions), conventions)
        assert said in figure.get_axes()[0].get_lines()[0].get_label()


def _mixed_splits() -> pd.DataFrame:
    """'Full' ran val_seen (2 episodes) and test_unseen (3); 'rule' test_unseen only (3),
    the same flights as Full's there (Table II's rule-based row is Table I's Full run)."""
    g = [square(0, 0), square(100, 0)]
    rows = [
        result([g[0], square(100 + k, 0)], g, episode_id=f"e{k}", system=system, split=split)
        for system, split, count in (
            ("Full", "test_unseen", 3),
            ("Full", "val_seen", 2),
            ("rule", "test_unseen", 3),
        )
        for k in range(count)
    ]
    return score_results(rows)


def test_systems_of_different_splits_are_not_pooled_silently() -> None:
    # An audit found Table II's test-only rows (n=30) drawn beside Table I's rows pooled
    # over three splits (n=90) under a title saying all splits were pooled.
    scores = _mixed_splits()
    for figure in (
        sr_vs_threshold_figure(scores, MetricConventions()),
        ne_distribution_figure(scores),
    ):
        axes = figure.get_axes()
        assert [ax.get_title().split(" (")[0] for ax in axes] == [
            "episodes of val_seen",
            "episodes of test_unseen",
        ]
        legends = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in axes]
        assert legends[0][0].startswith("Full (n=2")
        assert [entry.split(" (")[0] for entry in legends[1][:2]] == ["Full", "rule"]
        assert all("(n=3" in entry for entry in legends[1][:2])
    # Chosen splits or systems that ran the same ones: one panel, its splits named.
    one = sr_vs_threshold_figure(scores, MetricConventions(), splits=["test_unseen"])
    assert [ax.get_title() for ax in one.get_axes()] == ["episodes of test_unseen"]
    pooled = ne_distribution_figure(scores, systems=["Full"])
    assert [ax.get_title() for ax in pooled.get_axes()] == [
        "episodes of val_seen, test_unseen pooled"
    ]
    assert _legend(pooled)[0].startswith("Full (n=5")
    with pytest.raises(MetricInputError, match="no scores of split\\(s\\) 'val_unseen'"):
        sr_vs_threshold_figure(scores, MetricConventions(), splits=["val_unseen"])
    with pytest.raises(MetricInputError, match="system\\(s\\) 'rule' have no scores on"):
        ne_distribution_figure(scores, systems=["Full", "rule"], splits=["val_seen"])
    # Not named, a system without scores there is left out, and said to be.
    with pytest.warns(UserWarning, match="left out: system\\(s\\) 'rule', which have no"):
        only_full = ne_distribution_figure(scores, splits=["val_seen"])
    assert [entry.split(" (")[0] for entry in _legend(only_full)] == ["Full"]
    with pytest.raises(MetricInputError, match="'Ful'; the scores have the systems 'Full'"):
        ne_distribution_figure(scores, systems=["Ful"])


def test_the_two_episode_modes_are_never_drawn_as_one_line() -> None:
    """ANDH and ANDH-Full episodes of one system (their ids overlap) were drawn as one
    line under one n, the shared episodes counted twice."""
    g = [square(0, 0), square(100, 0)]
    rows = [
        result([g[0], square(100 + k, 0)], g, episode_id=f"e{k}", mode=mode)
        for mode, count in (("andh", 3), ("andh-full", 2))
        for k in range(count)
    ]
    scores = score_results(rows)
    with pytest.raises(MetricInputError, match=r"modes 'andh', 'andh-full'.*choose one"):
        sr_vs_threshold_figure(scores, MetricConventions())
    with pytest.raises(MetricInputError, match="choose one"):
        ne_distribution_figure(scores)
    andh = sr_vs_threshold_figure(scores, MetricConventions(), mode="andh")
    assert _legend(andh)[0].startswith("agent (n=3")
    assert andh.get_axes()[0].get_title() == "episodes of val_seen"
    full = ne_distribution_figure(scores, mode="andh-full")
    assert _legend(full)[0].startswith("agent (n=2")
    assert full.get_axes()[0].get_title() == "ANDH-Full episodes of val_seen"
    with pytest.raises(MetricInputError, match="no scores of mode 'andh-full'"):
        ne_distribution_figure(score_results(rows[:3]), mode="andh-full")


def test_every_system_has_a_style_of_its_own_and_its_axis_label_shows() -> None:
    # With 11 systems the colour cycle wrapped: the 1st and 11th lines looked the same,
    # and the y-axis label was cut off at the top.
    g = [square(0, 0), square(100, 0)]
    systems = [f"S{k}" for k in range(11)] + ["truth"]
    rows = [
        result([g[0], square(100 + k, 0)], g, episode_id=f"e{k}", system=system,
               extra={"oracle": True} if system == "truth" else {})
        for system in systems
        for k in range(2)
    ]  # fmt: skip
    scores = score_results(rows)
    sr = sr_vs_threshold_figure(scores, MetricConventions())
    ax = sr.get_axes()[0]
    styles = [(line.get_color(), line.get_linestyle()) for line in ax.get_lines()[:12]]
    assert len(set(styles)) == 12
    assert styles[-1][1] == "-."  # the reference, as before
    ne = ne_distribution_figure(scores)
    patches = [(p.get_edgecolor(), p.get_linestyle()) for p in ne.get_axes()[0].patches]
    assert len(set(patches)) == 12
    renderer = sr.canvas.get_renderer()  # type: ignore[attr-defined]
    sr.draw(renderer)
    label = ax.yaxis.label.get_window_extent(renderer)
    assert sr.bbox.y0 <= label.y0 and label.y1 <= sr.bbox.y1
