"""The recorded runs behind the paper's control figures: files, columns and sane values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skyvln_eval.control import (
    LOG_COLUMNS,
    PAPER_CASES,
    load_flight_log,
    record_paper_runs,
    recordings,
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], Path]:
    # Interpreted MPCs: the figures' runs do not need a compiler.
    real = recordings.make_controller

    def interpreted(name: str, settings: dict[str, object] | None = None):  # type: ignore[no-untyped-def]
        return real(name, {"compile": "never"} if name != "pid" else {})

    mp = pytest.MonkeyPatch()
    mp.setattr(recordings, "make_controller", interpreted)
    try:
        return record_paper_runs(tmp_path_factory.mktemp("paper-runs"))
    finally:
        mp.undo()


def test_every_controller_and_case_is_recorded(runs: dict[tuple[str, str], Path]) -> None:
    assert set(runs) == {(c, case) for c in ("pid", "mpc", "nmpc") for case in PAPER_CASES}
    for (name, case), path in runs.items():
        assert path.name == f"{case}_{name}.parquet"
        log = load_flight_log(path)
        assert list(log.columns[: len(LOG_COLUMNS)]) == list(LOG_COLUMNS)
        assert log.controller.unique().tolist() == [name]
        assert log.scenario.unique().tolist() == [f"paper_{case}"]
        assert log.attrs["settings"]["case"] == case


def test_the_runs_have_what_the_figures_need(runs: dict[tuple[str, str], Path]) -> None:
    for path in runs.values():
        log = load_flight_log(path)
        assert np.all(np.diff(log.t_s) > 0)
        for axis in ("x_m", "y_m", "z_m", "yaw_rad"):
            assert np.isfinite(log[axis]).all() and np.isfinite(log[f"ref_{axis}"]).all()
        assert (
            np.isfinite(log[["roll_rad", "pitch_rad", "cmd_roll_rad", "cmd_pitch_rad"]]).all().all()
        )
        # The route: 20 m east climbing 2 m, then 15 m north, turning to face north.
        # (the second segment starts where the first one arrived, within its tolerance)
        assert log.ref_x_m.max() == pytest.approx(20.0, abs=0.5)
        assert log.ref_y_m.max() == pytest.approx(15.0, abs=1e-3)
        assert log.ref_yaw_rad.iloc[-1] == pytest.approx(np.pi / 2)
        assert abs(log.x_m.iloc[-1] - 20.0) < 0.6 and abs(log.y_m.iloc[-1] - 15.0) < 0.6
        assert np.abs(log[["roll_rad", "pitch_rad"]]).max().max() < 0.5


def test_the_mpcs_avoid_what_pid_hits(runs: dict[tuple[str, str], Path]) -> None:
    for case in PAPER_CASES:
        for name in ("mpc", "nmpc"):
            log = load_flight_log(runs[(name, case)])
            assert (log.min_clearance_m >= 0.0).all()
            assert not log.solve_failed.any()
            assert log.min_clearance_m.min() < 0.3  # the obstacles were in the way
        pid = load_flight_log(runs[("pid", case)])
        assert pid.collision.any()


def test_plot_control_names_the_figures_as_reproduce_does(
    runs: dict[tuple[str, str], Path], tmp_path: Path
) -> None:
    # reproduce writes figures/control_<case>.png; drawing them again from its control_runs/
    # must give the same names (not control_paper_<case>.png beside them).
    from typer.testing import CliRunner

    from skyvln_eval.cli import app

    logs = [str(runs[(name, "dynamic")]) for name in ("pid", "nmpc")]
    plotted = CliRunner().invoke(app, ["plot", "control", *logs, "--out", str(tmp_path)])
    assert plotted.exit_code == 0, plotted.output
    assert [p.name for p in tmp_path.iterdir()] == ["control_dynamic.png"]
