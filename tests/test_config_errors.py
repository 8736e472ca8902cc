"""A misspelt config field is named with the field it was probably meant to be."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from pydantic import ValidationError

from skyvln_eval.errors import ConfigError, describe_validation_error
from skyvln_eval.harness.config import RunConfig, load_run_config
from skyvln_eval.harness.plan import ReproducePlan
from skyvln_eval.llm import LLMConfig


def _problems(model: type, data: dict[str, object]) -> str:
    with pytest.raises(ValidationError) as caught:
        model.model_validate(data)  # type: ignore[attr-defined]
    return describe_validation_error(caught.value, model)


def test_a_misspelt_field_gets_the_close_names_at_its_own_depth() -> None:
    text = _problems(
        RunConfig, {"system": "x", "agent": {"name": "skyvln", "llm": {"temperatur": 0.5}}}
    )
    assert "agent.llm.temperatur: Extra inputs are not permitted" in text
    assert "(did you mean 'temperature', 'repair_temperature'?)" in text


def test_inside_a_list_the_items_fields_are_offered() -> None:
    data = {"table1": {"systems": [{"label": "Full", "agent": {}, "controler": "nmpc"}]}}
    text = _problems(ReproducePlan, data)
    assert "table1.systems.0.controler: Extra inputs are not permitted" in text
    assert "(did you mean 'controller', 'controller_settings'?)" in text


def test_without_a_close_name_the_known_ones_are_listed() -> None:
    text = _problems(RunConfig, {"system": "x", "zzz": 1})
    assert "zzz: Extra inputs are not permitted (known: system, data, splits," in text


def test_without_the_model_the_message_is_pydantics() -> None:
    with pytest.raises(ValidationError) as caught:
        RunConfig.model_validate({"system": "x", "temperatur": 1})
    assert describe_validation_error(caught.value).endswith("Extra inputs are not permitted")


def test_an_unquoted_episode_id_read_as_a_number_says_to_quote_it(tmp_path: Path) -> None:
    path = tmp_path / "run.yaml"
    path.write_text('system: x\nepisodes: [9101__6_1, "9101__5_1"]\n')
    with pytest.raises(ConfigError) as caught:
        load_run_config(path)
    assert str(caught.value) == (
        f"run config {path}: episodes: episode ids are text, but 910161 is a number: YAML "
        "reads an unquoted id such as 9101__6_1 as the number 910161; quote each id: "
        '["9101__6_1", ...]'
    )
    path.write_text('system: x\nepisodes: ["9101__6_1"]\n')
    assert load_run_config(path).episodes == ("9101__6_1",)


@pytest.mark.parametrize(
    ("value", "read"),
    [
        ("off", "YAML reads unquoted yes / no / on / off / true / false as false"),
        ("1_5", "YAML reads the unquoted text as the number 15, an underscore in digits"),
    ],
)
def test_text_that_yaml_reads_as_a_scalar_says_to_quote_it(
    tmp_path: Path, value: str, read: str
) -> None:
    path = tmp_path / "run.yaml"
    path.write_text(f"system: {value}\n")
    with pytest.raises(ConfigError, match="system: Input should be a valid string") as caught:
        load_run_config(path)
    assert f"({read}" in str(caught.value) and "put the text in quotes)" in str(caught.value)
    plan = {"table1": {"systems": [{"label": 1.5}]}}
    assert "YAML reads the unquoted text as the number 1.5" in _problems(ReproducePlan, plan)


def test_a_server_in_the_backend_is_its_base_url_as_in_the_environment_form() -> None:
    from skyvln_eval.llm import LLMConfig

    config = LLMConfig(backend="openai:gpt-4o-mini@http://127.0.0.1:8080/v1")
    # Read as a model name, the server went to api.openai.com with the key of the user.
    assert (config.backend, config.base_url) == ("openai:gpt-4o-mini", "http://127.0.0.1:8080/v1")
    assert config == LLMConfig(backend="openai:gpt-4o-mini", base_url="http://127.0.0.1:8080/v1")
    # A model id may hold '@' (a version): without a URL after it, it stays the model's.
    assert LLMConfig(backend="openai:claude-3-5@20240620").base_url is None
    with pytest.raises(ValidationError, match=r"names the server .* give it once"):
        LLMConfig(backend="openai:m@http://a/v1", base_url="http://b/v1")


def test_a_plans_agent_settings_are_checked_on_load_naming_their_place(tmp_path: Path) -> None:
    from skyvln_eval.harness.plan import load_plan

    full = {"label": "Full", "mode": "official", "agent": {"name": "skyvln"}}
    plan = {
        "table1": {"splits": ["val_unseen"], "systems": [full, {**full, "label": "typo"}]},
        "table2": {"system": full, "backends": [{"label": "x", "llm": {"backend": "rule"}}]},
    }
    path = tmp_path / "plan.yaml"
    plan["table1"]["systems"][1]["agent"] = {"name": "skyvln", "llm": {"backend": "rulee"}}
    path.write_text(yaml.safe_dump(plan))
    with pytest.raises(ConfigError) as caught:
        load_plan(path)
    assert str(caught.value).startswith(
        f"reproduce plan {path}: table1.systems.1.agent.llm.backend: unknown LLM backend 'rulee'"
    )
    plan["table1"]["systems"][1]["agent"] = {"name": "skyvln"}
    plan["table2"]["backends"][0]["llm"] = {"backend": "rule", "temperatur": 0.2}
    path.write_text(yaml.safe_dump(plan))
    with pytest.raises(ConfigError, match=r"table2\.backends\.0\.llm\.temperatur: .*'temperature'"):
        load_plan(path)


def test_a_modules_budget_is_set_over_the_other_modules_defaults() -> None:
    from skyvln_eval.llm import LLMConfig
    from skyvln_eval.llm.config import DEFAULT_BUDGETS

    config = LLMConfig(budgets={"motion": 4096})
    assert config.generation("motion").max_tokens == 4096
    # The others keep theirs (they fell back to max_tokens: sub-goals 1024 -> 512).
    assert config.generation("subgoals").max_tokens == DEFAULT_BUDGETS["subgoals"] == 1024
    assert LLMConfig().budgets == DEFAULT_BUDGETS


def test_a_misspelt_modules_budget_is_refused_on_load(tmp_path: Path) -> None:
    from skyvln_eval.agent.vlm_detector import MODULE
    from skyvln_eval.llm.backends_file import load_backends_file
    from skyvln_eval.llm.config import LLM_MODULES

    # It was kept, and never used: the motion module ran at its default budget.
    path = tmp_path / "run.yaml"
    path.write_text("system: x\nagent: {llm: {backend: rule, budgets: {motoin: 4096}}}\n")
    with pytest.raises(ConfigError) as caught:
        load_run_config(path)
    assert str(caught.value).startswith(
        f"run config {path}: agent.llm.budgets: unknown agent module 'motoin'. "
        "Did you mean 'motion'? Known: clarify, detect, hsd_describe, hsd_rank, motion, "
        "navgpt, subgoals"
    )
    backends = tmp_path / "backends.yaml"
    backends.write_text(
        "format: skyvln-eval/llm-backends\nversion: 1\n"
        "backends: {local: {backend: rule, budgets: {motoin: 4096}}}\n"
    )
    with pytest.raises(ConfigError, match=rf"{backends}: local: budgets: .*'motoin'"):
        load_backends_file(backends)
    # Every module's name is known, the VLM detector's (which has no default) among them.
    assert MODULE in LLM_MODULES
    assert LLMConfig(budgets={"detect": 1024}).generation(MODULE).max_tokens == 1024


def test_a_backend_spec_is_checked_whole_in_backends_files_and_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from skyvln_eval.llm.backends_file import (
        BackendsFile,
        environment_backends,
        load_backends_file,
    )

    backends = tmp_path / "backends.yaml"
    backends.write_text(
        "format: skyvln-eval/llm-backends\nversion: 1\n"
        "backends: {old: {backend: 'replay:openai:'}}\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_backends_file(backends)
    assert str(caught.value) == (
        f"backends file {backends}: old: backend: the openai backend needs a model: "
        "'openai:<model>', e.g. 'openai:gpt-4o'"
    )
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "openai:")
    with pytest.raises(ConfigError, match=r"^\$SKYVLN_TEST_BACKENDS: 'openai:' is not"):
        environment_backends("SKYVLN_TEST_BACKENDS", BackendsFile())
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "openai:a, openai:b,openai:a")
    with pytest.raises(ConfigError, match=r"'openai:a' is named twice \(as 'a'\)"):
        environment_backends("SKYVLN_TEST_BACKENDS", BackendsFile())
    # An entry that names no backend was the rule stand-in, its server ignored: a Table II
    # row labelled as a model that no model answered.
    backends.write_text(
        "format: skyvln-eval/llm-backends\nversion: 1\n"
        "backends: {g: {base_url: 'http://127.0.0.1:8080/v1'}}\n"
    )
    with pytest.raises(ConfigError, match=r"backend 'g' does not say which backend it is"):
        load_backends_file(backends)
    # A name YAML reads as a boolean was the backend "False" (an audit).
    backends.write_text(
        "format: skyvln-eval/llm-backends\nversion: 1\nbackends: {no: {backend: rule}}\n"
    )
    with pytest.raises(ConfigError, match=r"backend name False is not text .*: quote it"):
        load_backends_file(backends)
    # With a file that names none, a bad spec says so, not "set the file" (an audit).
    backends.write_text("format: skyvln-eval/llm-backends\nversion: 1\n")
    loaded = load_backends_file(backends)
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "gemma")
    with pytest.raises(ConfigError, match=rf"and the backends file {backends} names no backend"):
        environment_backends("SKYVLN_TEST_BACKENDS", loaded)


def test_the_shipped_backends_file_loads_and_asks_the_local_server_as_the_plan_does() -> None:
    from skyvln_eval.harness.plan import load_plan
    from skyvln_eval.llm.backends_file import load_backends_file
    from tests.conftest import REPO

    shipped = load_backends_file(REPO / "skyvln_eval" / "configs" / "llm" / "backends.yaml")
    assert {"gpt-4o-mini", "local-gemma"} <= set(shipped.backends)
    planned = LLMConfig.model_validate(load_plan("local-llm").table2.backends[0].llm)
    local = shipped.backends["local-gemma"]
    same = ("backend", "base_url", "system_role", "timeout_s", "max_concurrency", "budgets")
    assert {k: getattr(local, k) for k in same} == {k: getattr(planned, k) for k in same}


def test_an_option_the_executor_would_not_use_is_refused() -> None:
    from skyvln_eval.harness.executors import make_executor

    with pytest.raises(ConfigError, match=r"threads_per_worker .* is for the processes executor"):
        make_executor("serial", 1, threads_per_worker=4)
    with pytest.raises(ConfigError, match=r"ray_address .* is for the ray executor"):
        make_executor("threads", 2, address="1.2.3.4:10001")
    make_executor("processes", 1, threads_per_worker=2)  # what it is for


def test_a_misspelt_plan_name_lists_the_shipped_plans() -> None:
    from skyvln_eval.harness.plan import load_plan

    with pytest.raises(ConfigError, match=r"unknown plan 'defualt'\. Did you mean 'default'\?"):
        load_plan("defualt")


@pytest.mark.parametrize(
    ("model", "where", "value"),
    [
        (RunConfig, "workers", True),
        (RunConfig, "limit", True),
        (RunConfig, "agent.detector.miss_rate", True),
        (RunConfig, "agent.perception.headings", True),
        (RunConfig, "dynamics.obstacles.n_obstacles", True),
        (RunConfig, "dynamics.plant.wind_mean_m_s", [True, False, False]),
        (RunConfig, "sensors.max_depth_m", True),
        (LLMConfig, "timeout_s", True),
        (LLMConfig, "max_concurrency", False),
    ],
)
def test_a_boolean_is_not_taken_for_a_number(model: type, where: str, value: object) -> None:
    # An audit: pydantic's lax mode read YAML's true as 1 and false as 0, without a word.
    data: dict[str, object] = {"system": "s"} if model is RunConfig else {}
    *parents, leaf = where.split(".")
    inner = data
    for key in parents:
        inner = inner.setdefault(key, {})  # type: ignore[assignment]
    inner[leaf] = value
    index = ".0" if isinstance(value, list) else ""
    assert _problems(model, data) == (
        f"{where}{index}: expected a number, got a boolean (YAML reads unquoted true / false / "
        "yes / no / on / off as booleans)"
    )


def test_boolean_settings_still_take_booleans() -> None:
    config = RunConfig.model_validate({"system": "s", "write_logs": False, "agent": {"hsd": False}})
    assert not config.write_logs and not config.agent.hsd
