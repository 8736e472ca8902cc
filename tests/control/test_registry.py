"""Controllers by name and from YAML, with errors that name the field."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from skyvln_eval.control import (
    LinearMpcController,
    MpcConfig,
    NmpcController,
    PidController,
    config_from_mapping,
    controller_config,
    controller_names,
    load_controller,
    make_controller,
)
from skyvln_eval.errors import ConfigError, SettingsError, UnknownNameError
from skyvln_eval.sim.quadrotor import QuadrotorParams
from tests.conftest import REPO

CONFIGS = sorted((REPO / "configs" / "controllers").glob("*.yaml"))


def test_the_paper_ablation_controllers_are_registered() -> None:
    assert controller_names() == ["mpc", "nmpc", "pid"]
    assert isinstance(make_controller("nmpc", {"compile": "never"}), NmpcController)
    assert isinstance(make_controller("mpc", {"compile": "never"}), LinearMpcController)
    assert isinstance(make_controller("lmpc", {"compile": "never"}), LinearMpcController)
    assert isinstance(make_controller("pid"), PidController)


def test_an_unknown_name_suggests_close_ones() -> None:
    with pytest.raises(UnknownNameError, match="Did you mean 'nmpc'"):
        make_controller("nmcp")


def test_nested_settings_override_the_defaults() -> None:
    ctl = make_controller(
        "nmpc",
        {
            "compile": "never",
            "horizon_steps": 10,
            "weights": {"state": [1, 1, 1, 1, 1, 1, 1, 1]},
            "limits": {"tilt_ref_step_max_rad": 0.05},
        },
    )
    assert isinstance(ctl, NmpcController)
    config = ctl.config
    assert config.horizon_steps == 10 and ctl.horizon_steps == 10
    assert config.weights.state == (1.0,) * 8
    assert config.weights.input == MpcConfig().weights.input
    assert config.limits.tilt_ref_step_max_rad == 0.05
    assert ctl.settings()["horizon_steps"] == 10


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"horizon": 10}, r"nmpc settings: unknown field 'horizon'. Did you mean 'horizon_steps'"),
        ({"horizon_steps": 2.5}, r"nmpc settings.horizon_steps must be an integer"),
        ({"horizon_steps": 0}, r"MpcConfig.horizon_steps must be an integer >= 1"),
        ({"weights": {"state": [1, 2]}}, r"MpcWeights.state must be 8"),
        ({"weights": {"input": "big"}}, r"nmpc settings.weights.input must be a list"),
        (
            {"limits": {"thrust_max_m_s2": "x"}},
            r"nmpc settings.limits.thrust_max_m_s2 must be a number",
        ),
        ({"compile": "sometimes"}, r"nmpc settings.compile must be one of"),
        ({"weights": 3}, r"nmpc settings.weights must be a mapping"),
    ],
)
def test_bad_settings_name_the_field(settings: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        make_controller("nmpc", settings)


def test_pid_settings_are_checked_too() -> None:
    with pytest.raises(ConfigError, match="velocity_feedforward must be true or false"):
        make_controller("pid", {"velocity_feedforward": "yes"})


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_the_shipped_controller_configs_load(path: Path, tmp_path: Path) -> None:
    # Interpreted, so this test never waits for a compiler; otherwise the file as shipped.
    copy = tmp_path / path.name
    copy.write_text(path.read_text().replace("compile: auto", "compile: never"))
    ctl = load_controller(copy)
    assert ctl.name == path.stem


def test_the_shipped_nmpc_config_spells_out_the_defaults() -> None:
    document = yaml.safe_load((REPO / "configs" / "controllers" / "nmpc.yaml").read_text())
    assert config_from_mapping(MpcConfig, document["settings"]) == MpcConfig()


def test_a_bad_config_file_names_the_file_and_the_field(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("controller: nmpc\nsettings:\n  weights: {input_rates: [1, 2, 3]}\n")
    with pytest.raises(
        ConfigError, match=r"bad.yaml: nmpc settings.weights: unknown field 'input_rates'"
    ):
        load_controller(path)
    path.write_text("controler: nmpc\n")
    with pytest.raises(
        ConfigError, match=r"bad.yaml: expected a mapping with a 'controller' field"
    ):
        load_controller(path)


def test_importing_control_imports_no_optional_heavy_dependency() -> None:
    heavy = ("ray", "transformers", "torch", "openai", "do_mpc")
    code = f"import sys, skyvln_eval.control\nprint([m for m in {heavy!r} if m in sys.modules])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]"


def test_controller_config_checks_settings_without_building_a_solver(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import skyvln_eval.control.mpc as mpc

    def no_solver(*args: object, **kwargs: object) -> None:
        raise AssertionError("a solver was built")

    monkeypatch.setattr(mpc.NmpcController, "__init__", no_solver)
    assert controller_config("nmpc", {"horizon_steps": 5}).horizon_steps == 5
    with pytest.raises(SettingsError) as caught:
        controller_config("nmpc", {"weights": {"state": [1, "x"]}})
    assert caught.value.field == "weights.state[1]"
    assert caught.value.problem == "must be a number, got 'x'"
    with pytest.raises(SettingsError) as caught:
        controller_config("lmpc", {"max_obstacle": 1})
    assert caught.value.field == "max_obstacle"
    assert caught.value.problem.endswith("(did you mean 'max_obstacles'?)")


def test_an_exponent_without_its_sign_is_named_as_yaml_text() -> None:
    document = yaml.safe_load("weights: {slack_linear: 1.0e12}")
    with pytest.raises(SettingsError) as caught:
        controller_config("nmpc", document)
    assert caught.value.problem == (
        "must be a number, got '1.0e12' (text: YAML wants a signed exponent, 1.0e+12)"
    )
    assert controller_config("nmpc", yaml.safe_load("weights: {slack_linear: 1.0e+12}"))


def test_a_control_step_longer_than_the_model_can_predict_is_refused() -> None:
    # One RK4 step per interval: for the attitude loop (tau 0.257 s) stable up to
    # 2.785 tau = 0.716 s. An audit's dt 1 s flew 53 m off a 20 m target, without a word.
    assert MpcConfig(dt_s=0.7).dt_s == 0.7
    with pytest.raises(ConfigError, match=r"dt_s must be at most 0\.716 s, got 1\.0"):
        MpcConfig(dt_s=1.0)
    slower = QuadrotorParams(roll_time_constant_s=0.5, pitch_time_constant_s=0.5)
    assert MpcConfig(dt_s=1.0, params=slower).dt_s == 1.0  # the limit is the model's
