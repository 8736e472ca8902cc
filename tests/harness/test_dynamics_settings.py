"""Dynamics settings a closed loop depends on: every obstacle in the controller's plan,
and the plant's wind and sensor noise (nominal by default), which reach the flight."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from skyvln_eval.control import load_flight_log
from skyvln_eval.errors import ConfigError
from skyvln_eval.harness import RunConfig, run
from skyvln_eval.harness.config import DynamicsSettings, PlantSettings
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import read_results

MakeConfig = Callable[..., RunConfig]
EIGHT = {"kind": "crossing", "n_obstacles": 8}


def test_obstacles_beyond_the_controllers_slots_are_refused_not_dropped() -> None:
    """An audit flew 8 obstacles with the NMPC's 2 slots: it planned around the 2 nearest
    and crashed in 6 of 18 episodes, none with 8 slots, and nothing said so."""
    with pytest.raises((ConfigError, ValueError), match=r"max_obstacles: 8"):
        DynamicsSettings.model_validate({"obstacles": EIGHT})
    DynamicsSettings.model_validate(
        {"obstacles": EIGHT, "controller_settings": {"max_obstacles": 8}}
    )
    # An MPC that ignores obstacles on purpose, a PID (no plan) and no obstacles at all.
    DynamicsSettings.model_validate(
        {"obstacles": EIGHT, "controller_settings": {"max_obstacles": 0}}
    )
    DynamicsSettings.model_validate({"obstacles": EIGHT, "controller": "pid"})
    DynamicsSettings.model_validate({"obstacles": {"kind": "none", "n_obstacles": 8}})


def test_the_plant_is_nominal_unless_wind_and_noise_are_set() -> None:
    nominal = PlantSettings()
    assert nominal.nominal and "nominal plant" in nominal.describe()
    windy = PlantSettings(
        wind_mean_m_s=(3.0, 4.0, 0.0), gust_std_m_s=1.0, position_noise_std_m=0.05
    )
    assert not windy.nominal and "wind 5 m/s (gusts 1 m/s)" in windy.describe()
    config = windy.plant_config()
    assert config.wind.mean_m_s == (3.0, 4.0, 0.0) and config.noise.position_std_m == 0.05
    # A vertical wind is wind (an audit's caption said "wind 0 m/s" for [0, 0, 15]).
    assert "wind 15 m/s" in PlantSettings(wind_mean_m_s=(0.0, 0.0, 15.0)).describe()


@pytest.mark.parametrize(
    "settings",
    [
        {"wind_mean_m_s": [1e200, 0, 0]},
        {"wind_mean_m_s": [0, 0, -101]},
        {"gust_std_m_s": 1e9},
        {"position_noise_std_m": 1e6},
        {"attitude_noise_std_rad": 4.0},
    ],
)
def test_wind_and_noise_past_any_flyable_case_are_refused(settings: dict[str, object]) -> None:
    # An audit: a wind of 1e200 m/s passed, and each episode's error named only numpy's
    # "Maximum allowed size exceeded".
    with pytest.raises(ValidationError, match="than or equal to"):
        PlantSettings.model_validate(settings)


@pytest.mark.parametrize("field", ["radius_m", "safety_radius_m"])
def test_an_obstacle_sphere_wider_than_a_segments_cruise_is_refused(field: str) -> None:
    # An audit's 30 m sphere held the drone at t = 0: a crash charged to the controller.
    with pytest.raises(ValidationError, match="less than or equal to 10"):
        DynamicsSettings.model_validate({"obstacles": {field: 30.0}})


def test_wind_and_noise_reach_the_flown_drone(tmp_path: Path, small_config: MakeConfig) -> None:
    def flown(name: str, plant: dict[str, object]) -> np.ndarray:
        dynamics = {
            "controller": "pid",
            "controller_settings": {},
            "obstacles": {"kind": "none"},
            "plant": plant,
        }
        config = small_config(mode="dynamics", splits=("val_seen",), limit=1, dynamics=dynamics)
        run(config, tmp_path / name)
        [row] = read_results(tmp_path / name / RESULTS_FILE)
        log = load_flight_log(tmp_path / name / str(row.control_log))
        return log[["x_m", "y_m", "z_m"]].to_numpy()

    nominal, again = flown("nominal", {}), flown("again", {})
    windy = flown("windy", {"wind_mean_m_s": (4.0, 0.0, 0.0), "gust_std_m_s": 1.0})
    np.testing.assert_array_equal(nominal, again)  # seeded: the same flight
    n = min(len(nominal), len(windy))
    assert np.abs(windy[:n] - nominal[:n]).max() > 0.05  # the wind pushed it


def test_the_tables_say_which_rows_flew_and_how_many_episodes_a_quick_look_took() -> None:
    from skyvln_eval.harness.plan import load_plan
    from skyvln_eval.harness.reproduce import setting_note

    plan = load_plan("default", limit=3)
    note = setting_note(plan)
    flown = [s.label for s in plan.table1.systems if s.mode == "dynamics"]
    stepped = [s.label for s in plan.table1.systems if s.mode != "dynamics"]
    assert flown and stepped  # the default plan has both
    assert f"flown by their controllers ({plan.dynamics.plant.describe()}): " in note
    assert f"the official AVDN step (no flight, no obstacles): {', '.join(stepped)}" in note
    assert "Episodes: the first 3 of each split" in note
    assert "Episodes:" not in setting_note(load_plan("default"))
    # Which data: the synthetic sets are AVDN's format, not AVDN (and keep test_unseen's
    # ground truth); a folder of the user's is named by its folder.
    assert note.startswith("Data: the synthetic sample (AVDN's format, not its imagery")
    real = plan.model_copy(update={"data": "/data/avdn"})
    assert setting_note(real).startswith("Data: avdn (AVDN format). Sensors: ")


def test_dynamics_settings_in_an_official_run_are_warned_of(
    tmp_path: Path, sample_dir: Path
) -> None:
    import yaml
    from typer.testing import CliRunner

    from skyvln_eval.cli import app

    config = tmp_path / "official.yaml"
    settings = {
        "system": "random", "data": str(sample_dir), "splits": ["val_seen"], "limit": 1,
        "workers": 1, "executor": "serial", "write_logs": False, "agent": {"name": "random"},
        "dynamics": {"controller": "pid"},
    }  # fmt: skip
    config.write_text(yaml.safe_dump(settings), encoding="utf-8")
    result = CliRunner().invoke(app, ["run", str(config), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "its dynamics settings are not used in mode official" in result.output
