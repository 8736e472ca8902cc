"""Bad configs and output paths get one clear message (file, field, what to do) and exit 2,
before any episode runs; never a traceback."""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from skyvln_eval.errors import ConfigError
from skyvln_eval.harness import load_run_config
from skyvln_eval.harness.plan import load_plan, planned_runs
from skyvln_eval.harness.preflight import PreflightError, preflight
from skyvln_eval.llm import LLMConfig
from tests.conftest import CliOutcome
from tests.harness.test_reproduce import TINY_PLAN

TINY_TABLE1 = TINY_PLAN["table1"]

Cli = Callable[..., CliOutcome]


def _config(sample_dir: Path, **overrides: Any) -> dict[str, Any]:
    return {
        "system": "bad input",
        "data": str(sample_dir),
        "splits": ["val_unseen"],
        "limit": 1,
        "executor": "serial",
        **overrides,
    }


def _plan_refused_on_load(tmp_path: Path, cli: Cli, change: dict[str, Any], needle: str) -> None:
    """``reproduce`` of the tiny plan with ``change`` is refused, naming the plan file and
    ``needle``, before any episode runs or its output folder is made."""
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump(TINY_PLAN | change))
    out = tmp_path / "out"
    _refused(cli("reproduce", "--plan", str(plan), "--out", str(out)), f"{plan}: {needle}")
    assert not out.exists(), "no episode may run, no folder be made"


def _refused(outcome: CliOutcome, *needles: str) -> str:
    """The one-line message of a refused command (exit 2, no traceback)."""
    assert outcome.code == 2, outcome
    assert "Traceback" not in outcome.err + outcome.out
    for needle in needles:
        assert needle in outcome.err, (needle, outcome.err)
    return outcome.err


def test_a_config_whose_top_level_is_a_list(tmp_path: Path, cli: Cli) -> None:
    path = tmp_path / "listed.yaml"
    path.write_text("- system: x\n- data: sample\n")
    _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        f"run config {path}",
        "the top level must be a mapping",
        "but it is a list",
    )
    assert not (tmp_path / "run").exists()


def test_a_config_that_is_not_utf8(tmp_path: Path, cli: Cli) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes("system: x\nagent: {name: skyvln}  # café\n".encode("latin-1"))
    _refused(
        cli("run", str(path)),
        f"run config {path}: not UTF-8 text (byte 0xe9 on line 2",
        "save it as UTF-8",
    )


def test_configs_that_are_folders_scalars_or_not_yaml(tmp_path: Path, cli: Cli) -> None:
    folder = tmp_path / "folder.yaml"
    folder.mkdir()
    _refused(cli("run", str(folder)), f"run config {folder}: cannot read it: Is a directory")
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("just some words\n")
    _refused(cli("run", str(scalar)), "but it is a single string")
    broken = tmp_path / "broken.yaml"
    broken.write_text("system: [unclosed\n")
    _refused(cli("run", str(broken)), f"run config {broken}: not valid YAML", "line 2")


def test_out_naming_an_existing_file(tmp_path: Path, sample_dir: Path, cli: Cli) -> None:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir)))
    existing = tmp_path / "results.txt"
    existing.write_text("my notes\n")
    _refused(
        cli("run", str(path), "--out", str(existing)),
        f"run directory {existing} is an existing file, not a folder",
    )
    assert existing.read_text() == "my notes\n"  # untouched
    _refused(
        cli("run", str(path), "--out", str(existing / "run")),
        f"run directory {existing / 'run'} cannot be created: {existing} is a file",
    )


def test_reproduce_out_naming_a_file_and_a_plan_that_is_a_list(tmp_path: Path, cli: Cli) -> None:
    existing = tmp_path / "out.txt"
    existing.write_text("x")
    _refused(
        cli("reproduce", "--out", str(existing), "--limit", "1"),
        f"output folder {existing} is an existing file",
    )
    plan = tmp_path / "plan.yaml"
    plan.write_text("- name: x\n")
    _refused(cli("reproduce", "--plan", str(plan)), f"reproduce plan {plan}", "it is a list")


def test_unknown_backend_controller_and_agent_fail_before_any_episode(
    tmp_path: Path, sample_dir: Path, cli: Cli
) -> None:
    path = tmp_path / "misspelt.yaml"
    config = _config(
        sample_dir,
        mode="dynamics",
        agent={"name": "skyvln", "llm": {"backend": "opneai:gpt-4o-mini"}},
        dynamics={"controller": "nmcp"},
    )
    path.write_text(yaml.safe_dump(config))
    message = _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        "agent.llm.backend: unknown LLM backend 'opneai'. Did you mean 'openai'?",
        "Known: openai, random, replay, rule, scripted",
        "dynamics.controller: unknown controller 'nmcp'. Did you mean 'nmpc'?",
        "Known: linear_mpc, lmpc, mpc, nmpc, pid",
    )
    assert "Value error" not in message
    path.write_text(yaml.safe_dump(_config(sample_dir, agent={"name": "skyvnl"})))
    _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        "agent: unknown agent 'skyvnl'. Did you mean 'skyvln'?",
    )
    assert not (tmp_path / "run").exists(), "no episode may run"


@pytest.mark.parametrize(
    ("backend", "problem"),
    [
        ("openai:", "the openai backend needs a model: 'openai:<model>'"),
        ("replay:", "replay needs the replayed backend: 'replay:<backend>:<model>'"),
        ("replay:openai:", "the openai backend needs a model"),
        ("rule:v2", "the rule backend has one version, 'rule-v1'; got 'v2'"),
    ],
)
def test_a_backend_without_a_usable_model_fails_before_any_episode(
    tmp_path: Path, sample_dir: Path, cli: Cli, backend: str, problem: str
) -> None:
    # Only the name was checked on load: every episode failed on the model, then the run
    # suggested --retry-failed.
    path = tmp_path / "no-model.yaml"
    config = _config(sample_dir, agent={"name": "skyvln", "llm": {"backend": backend}})
    path.write_text(yaml.safe_dump(config))
    _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        f"run config {path}: agent.llm.backend: {problem}",
    )
    assert not (tmp_path / "run").exists(), "no episode may run"


def test_a_missing_api_key_is_refused_before_any_episode(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # It was found by the first episode's call (an error row, the run stopped), and
    # reproduce ran every run before the first that called the model.
    monkeypatch.delenv("SKYVLN_TEST_KEY", raising=False)
    llm = {"backend": "openai:gpt-4o-mini", "api_key_env": "SKYVLN_TEST_KEY"}
    path = tmp_path / "no-key.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir, agent={"name": "skyvln", "llm": llm})))
    _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        f"run config {path}: agent.llm: openai:gpt-4o-mini@https://api.openai.com/v1: "
        "set the environment variable SKYVLN_TEST_KEY to the API key",
    )
    assert not (tmp_path / "run").exists(), "no episode may run"
    with pytest.raises(PreflightError, match=r"^run 'bad input': agent\.llm: openai:gpt-4o-mini@"):
        preflight(load_run_config(path), sample_dir, [])  # run() from Python checks it too
    vlm = {"name": "vlm", "llm": {**llm, "backend": "openai:gpt-4o"}}
    agent = {"name": "skyvln", "detector": vlm, "llm": {**llm, "base_url": "http://127.0.0.1:9/v1"}}
    path.write_text(yaml.safe_dump(_config(sample_dir, agent=agent)))
    _refused(  # a local server needs no key; the detector's model on OpenAI's does
        cli("run", str(path), "--out", str(tmp_path / "run")),
        f"run config {path}: agent.detector.llm: openai:gpt-4o@https://api.openai.com/v1: set",
    )
    monkeypatch.setenv("SKYVLN_EVAL_BACKENDS", "openai:gpt-4o-mini")
    monkeypatch.delenv("SKYVLN_EVAL_BACKENDS_FILE", raising=False)
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    out = tmp_path / "out"
    message = _refused(
        cli("reproduce", "--data-dir", str(sample_dir), "--out", str(out), "--limit", "1"),
        "$SKYVLN_EVAL_BACKENDS: backend 'gpt-4o-mini': agent.llm: openai:gpt-4o-mini@"
        "https://api.openai.com/v1: set the environment variable OPENAI_API_KEY to the API key",
    )
    assert "--retry-failed" not in message
    assert list(out.iterdir()) == [], "no run may start"
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-not-a-key")
    with_key = load_plan("default")
    assert any(
        r.config.agent.llm.backend == "openai:gpt-4o-mini"
        for r in planned_runs(with_key, tmp_path, 1, "serial")
    )


def test_a_server_without_its_scheme_is_refused_on_load(
    tmp_path: Path, sample_dir: Path, cli: Cli
) -> None:
    # As base_url, every call failed to connect; after '@', it was read as part of the
    # model's name and the calls (with the key) went to api.openai.com.
    path = tmp_path / "no-scheme.yaml"
    for llm, field in (
        ({"backend": "openai:m", "base_url": "127.0.0.1:8080/v1"}, "agent.llm.base_url"),
        ({"backend": "openai:m@127.0.0.1:8080/v1"}, "agent.llm"),
    ):
        path.write_text(yaml.safe_dump(_config(sample_dir, agent={"name": "skyvln", "llm": llm})))
        _refused(
            cli("run", str(path), "--out", str(tmp_path / "run")),
            field,
            "'127.0.0.1:8080/v1' is not an http(s) URL with a host: write "
            "http://127.0.0.1:8080/v1 (or https://)",
        )
    assert not (tmp_path / "run").exists(), "no episode may run"
    # A model id may hold an '@' of its own; a server with its scheme is taken.
    assert LLMConfig(backend="openai:m@2024").backend == "openai:m@2024"
    assert LLMConfig(backend="openai:m@v1.2").base_url is None
    served = LLMConfig(backend="openai:m@https://api.example.com/v1")
    assert (served.backend, served.base_url) == ("openai:m", "https://api.example.com/v1")
    with pytest.raises(Exception, match="a server is an http:// or https:// URL"):
        LLMConfig(base_url="ftp://example.com/v1")
    # After '@', a server of another scheme was part of the model's name (to OpenAI's).
    with pytest.raises(Exception, match="the server 'ftp://x' is not an http"):
        LLMConfig(backend="openai:gpt@ftp://x")


def test_known_names_and_aliases_still_load(tmp_path: Path) -> None:
    path = tmp_path / "alias.yaml"
    path.write_text("system: x\ndynamics: {controller: lmpc}\nagent: {llm: {backend: rule}}\n")
    assert load_run_config(path).dynamics.controller == "lmpc"
    replay = LLMConfig(backend="replay:openai:gpt-4o", cache_path=str(tmp_path / "c.sqlite"))
    assert replay.backend == "replay:openai:gpt-4o"
    with pytest.raises(Exception, match="answers only from the response cache: set cache_path"):
        LLMConfig(backend="replay:openai:gpt-4o")  # refused on load, not in every episode
    with pytest.raises(Exception, match="unknown LLM backend 'opena'"):
        LLMConfig(backend="opena:gpt-4o")


def test_a_damaged_config_in_the_run_directory_is_named(
    tmp_path: Path, sample_dir: Path, cli: Cli
) -> None:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir)))
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.yaml").write_bytes(b"system: \xff\xfe\n")  # edited by hand, badly
    _refused(
        cli("run", str(path), "--out", str(run_dir)),
        f"run config {run_dir / 'config.yaml'}: not UTF-8 text",
    )


def test_load_run_config_raises_config_errors_only(tmp_path: Path) -> None:
    for text in (b"- a\n", b"\xff\n", b"a: [\n", b"42\n"):
        path = tmp_path / "c.yaml"
        path.write_bytes(text)
        with pytest.raises(ConfigError, match=str(path)):
            load_run_config(path)


@pytest.mark.parametrize(
    ("dynamics", "needle"),
    [
        (
            {"controller": "pid", "controller_settings": {"horizn": 5}},
            "dynamics.controller_settings.horizn: unknown field of the pid settings (known: dt_s,",
        ),
        (
            {"controller": "mpc", "controller_settings": {"max_obstacle": 1}},
            "dynamics.controller_settings.max_obstacle: unknown field of the mpc settings "
            "(did you mean 'max_obstacles'?)",
        ),
        (
            {"controller": "nmpc", "controller_settings": {"weights": {"input": "big"}}},
            "dynamics.controller_settings.weights.input: must be a list, got 'big'",
        ),
        (
            {"controller": "nmpc", "controller_settings": {"horizon_steps": 0}},
            "dynamics.controller_settings: MpcConfig.horizon_steps must be an integer >= 1",
        ),
    ],
    ids=["pid-unknown", "mpc-misspelt", "nmpc-type", "nmpc-range"],
)
def test_bad_controller_settings_are_refused_on_load(
    tmp_path: Path, sample_dir: Path, cli: Cli, dynamics: dict[str, Any], needle: str
) -> None:
    path = tmp_path / "settings.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir, mode="dynamics", dynamics=dynamics)))
    _refused(cli("run", str(path), "--out", str(tmp_path / "run")), f"run config {path}: {needle}")
    assert not (tmp_path / "run").exists(), "no episode may run"


def test_bad_controller_settings_in_a_plan_are_refused_on_load(tmp_path: Path, cli: Cli) -> None:
    plan = tmp_path / "plan.yaml"
    systems = [
        {"label": "w PID", "controller": "pid", "controller_settings": {"max_speed": 3}},
        {"label": "w MPC", "controller": "mpc", "agent": {"name": "skyvln"}},
    ]
    data = TINY_PLAN | {"dynamics": {}, "table1": {"splits": ["val_unseen"], "systems": systems}}
    plan.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    _refused(
        cli("reproduce", "--plan", str(plan), "--out", str(out)),
        f"reproduce plan {plan}: table1.systems.0.controller_settings.max_speed: unknown field "
        "of the pid settings (did you mean 'max_speed_m_s'?)",
    )
    # The plan's settings go to every system: a PID has no such field.
    systems[0] = {"label": "w PID", "controller": "pid"}
    data["dynamics"] = {"controller_settings": {"compile": "never"}}
    plan.write_text(yaml.safe_dump(data))
    _refused(
        cli("reproduce", "--plan", str(plan), "--out", str(out)),
        "dynamics.controller_settings.compile: unknown field of the pid settings",
        "system 'w PID' flies pid",
    )
    systems[0] = {"label": "w PID", "controller": "pdi"}
    plan.write_text(yaml.safe_dump(data))
    _refused(
        cli("reproduce", "--plan", str(plan), "--out", str(out)),
        "table1.systems.0.controller: unknown controller 'pdi'. Did you mean 'pid'?",
    )
    assert not out.exists(), "no episode may run"


def test_an_invalid_record_is_named_with_what_a_run_can_do_about_it(
    tmp_path: Path, dataset_factory: Callable[..., Path], cli: Cli
) -> None:
    from tests.conftest import make_record

    bad = make_record(route_index="1_1", angle="x")
    data = dataset_factory({"val_unseen": [make_record(), bad]})
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({**_config(data), "data": str(data)}))
    message = _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        "1 invalid record(s) (a run needs every record of its splits: fix them; "
        "`skyvln-eval validate DATA_DIR` lists every problem",
        "record 1 (episode 1913__1_1), field 'angle'",
    )
    assert "skip_invalid" not in message and "--skip-invalid to skip" not in message
    # reproduce has no --skip-invalid either (it suggested it, as the loader's hint does).
    outcome = cli("reproduce", "--data-dir", str(data), "--out", str(tmp_path / "out"))
    message = _refused(outcome, "1 invalid record(s) (a run needs every record of its splits")
    assert "`--skip-invalid` with" not in message and "skip_invalid" not in message
    # Where records are loaded, the hint names the options that do leave them out.
    outcome = cli("summary", str(data))
    assert outcome.code == 2 and "`--skip-invalid` with `skyvln-eval summary`" in outcome.err


def test_an_episode_whose_log_cannot_be_made_stops_the_run_that_covers_it(
    tmp_path: Path,
    dataset_factory: Callable[..., Path],
    cli: Cli,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # An audit: the run went on without it (29 of 30 episodes, no note) and a limit took
    # the next episode in its place.
    import errno

    from skyvln_eval.converters import batch
    from tests.conftest import make_record

    def disk_full_for_1914(episode: Any, *args: Any, **kwargs: Any) -> Any:
        if episode.map_name == "1914":
            raise OSError(errno.ENOSPC, "No space left on device")
        return convert(episode, *args, **kwargs)

    convert = batch.convert_episode
    monkeypatch.setattr(batch, "convert_episode", disk_full_for_1914)
    data = dataset_factory(
        {"val_unseen": [make_record(), make_record(map_name="1914")]}, maps=("1913", "1914")
    )
    path = tmp_path / "run.yaml"
    random = {"data": str(data), "agent": {"name": "random"}}
    path.write_text(yaml.safe_dump({**_config(data), **random, "limit": 2}))
    _refused(
        cli("run", str(path), "--out", str(tmp_path / "run")),
        "1 episode(s) of the run could not be converted to episode logs",
        "val_unseen/1914__0_1: ",
    )
    assert not (tmp_path / "run" / "results.jsonl").exists(), "no episode may run"
    # A run that does not cover it goes on: the limit is counted over every episode.
    path.write_text(yaml.safe_dump({**_config(data), **random, "limit": 1}))
    outcome = cli("run", str(path), "--out", str(tmp_path / "first"))
    assert outcome.code == 0, outcome


def test_a_bad_option_is_named_as_the_option_not_as_the_config(
    tmp_path: Path, sample_dir: Path, cli: Cli
) -> None:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir, workers=0)))
    message = _refused(
        cli("run", str(path), "--executor", "bogus", "--threads-per-worker", "100"),
        f"run config {path}: workers: Input should be greater than or equal to 1",
        "--executor 'bogus': Input should be 'serial', 'processes', 'threads' or 'ray'",
        "--threads-per-worker 100: Input should be less than or equal to 64",
    )
    assert "executor:" not in message  # not as if the file said it
    out = tmp_path / "out"
    _refused(
        cli("reproduce", "--executor", "bogus", "--out", str(out)),
        "--executor: unknown executor 'bogus'. Known: processes, ray, serial, threads",
    )
    assert not out.exists()


def test_a_local_model_server_that_is_not_running_is_refused_before_any_episode(
    tmp_path: Path, sample_dir: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Without the server, every call failed and the run (or the local-llm plan) ended as
    # columns of "error" cells, the reason found only in each episode's record.
    with socket.socket() as probe:  # a port nothing listens on once this is closed
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    url = f"http://127.0.0.1:{port}/v1"
    agent = {"name": "skyvln", "llm": {"backend": "openai:gemma", "base_url": url}}
    path = tmp_path / "no-server.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir, agent=agent)))
    outcome = cli("run", str(path), "--out", str(tmp_path / "run"))
    _refused(outcome, f"run 'bad input': agent.llm: nothing answers at {url}", "start the server")
    assert not list((tmp_path / "run").glob("**/results.jsonl")), "no episode may run"
    # Named in $SKYVLN_EVAL_BACKENDS, reproduce refuses it before any run folder is made
    # (an audit found all 28 made first, each with a run.json saying "not finished").
    monkeypatch.setenv("SKYVLN_EVAL_BACKENDS", f"openai:gemma@{url}")
    out = tmp_path / "reproduce"
    outcome = cli("reproduce", "--data-dir", str(sample_dir), "--out", str(out), "--limit", "1")
    _refused(outcome, f"agent.llm: nothing answers at {url}")
    assert not (out / "runs").exists()
    with socket.socket() as server:  # something listening there: the run goes ahead
        server.bind(("127.0.0.1", port))
        server.listen()
        preflight(load_run_config(path), sample_dir, [])


@pytest.mark.parametrize(
    ("lines", "needle"),
    [
        # NaN and infinity passed the range checks and became null in the copy each
        # episode reads: a raw ValidationError from inside the run, a run.json left behind.
        ("sensors: {max_depth_m: .inf}", "sensors.max_depth_m: Input should be a finite number"),
        (
            "mode: dynamics\ndynamics: {plant: {wind_mean_m_s: [.nan, 0, 0]}}",
            "dynamics.plant.wind_mean_m_s.0: Input should be a finite number",
        ),
        ("agent: {detector: {close_look_m: .inf}}", "agent.detector.close_look_m"),
        # YAML keeps the last of a repeated key without a word: the run was 'b'.
        ("system: b", "found the key 'system' twice (first on line "),
        ("seed: " + "7" * 5000, "a value that cannot be read: Exceeds the limit"),
        ("episodes: []", "episodes: an empty list selects no episode"),
    ],
    ids=["inf", "nan", "nested-inf", "repeated-key", "huge-integer", "no-episodes"],
)
def test_values_no_setting_can_take_are_refused_on_load(
    tmp_path: Path, sample_dir: Path, cli: Cli, lines: str, needle: str
) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(_config(sample_dir)) + lines + "\n")
    _refused(cli("run", str(path), "--out", str(tmp_path / "run")), str(path), needle)
    assert not (tmp_path / "run").exists(), "no episode may run"


@pytest.mark.parametrize(
    ("setting", "needle"),
    [
        ({"seed": -1}, "seed: Input should be greater than or equal to 0"),
        ({"seed": 2**80}, "seed: Input should be less than or equal to 9223372036854775807"),
        ({"resamples": 10**23}, "resamples: Input should be less than or equal to 1000000"),
    ],
    ids=["negative-seed", "huge-seed", "huge-resamples"],
)
def test_a_plans_bootstrap_numpy_cannot_take_is_refused_before_any_run(
    tmp_path: Path, cli: Cli, setting: dict[str, int], needle: str
) -> None:
    # An audit: `seed: -1` flew every run, then scoring failed with a traceback.
    _plan_refused_on_load(tmp_path, cli, setting, needle)


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        # An audit: each loaded, then a raw pydantic traceback when the runs were made.
        ({"max_action_len": 200}, "max_action_len: Input should be less than or equal to 100"),
        (
            {"dynamics": {"obstacles": {"n_obstacles": 3}}},
            "table1.systems.1: system 'Full' flying nmpc with the plan's settings: dynamics: "
            "controller 'nmpc' plans around its 2 nearest obstacles",
        ),
        # An audit: a plan's controller was ignored, every system flying its own.
        (
            {"dynamics": {"controller": "pid"}},
            "dynamics.controller: a plan sets each system's controller",
        ),
        # An audit: the first failed after every run, the second was a traceback.
        (
            {"control_figures": {"controllers": ["nmcp"], "cases": ["static"]}},
            "control_figures.controllers.0: unknown controller 'nmcp'. Did you mean 'nmpc'?",
        ),
        (
            {"control_figures": {"controllers": ["pid"], "cases": ["dynmic"]}},
            "control_figures.cases.0: Input should be 'static' or 'dynamic'",
        ),
        # An audit: said as a row label given twice.
        (
            {"table1": {**TINY_TABLE1, "splits": ["val_seen", "val_seen"]}},
            "table1.splits: split(s) val_seen listed more than once",
        ),
    ],
    ids=[
        "max-action-len",
        "obstacles-beyond-slots",
        "plan-controller",
        "figure-controller",
        "figure-case",
        "split-twice",
    ],
)
def test_a_plan_whose_runs_or_figures_would_fail_is_refused_on_load(
    tmp_path: Path, cli: Cli, change: dict[str, Any], needle: str
) -> None:
    _plan_refused_on_load(tmp_path, cli, change, needle)


def test_a_planned_run_the_options_make_invalid_is_a_config_error(tmp_path: Path) -> None:
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump(TINY_PLAN))
    with pytest.raises(ConfigError, match=r"^reproduce plan 'tiny': system 'NavGPT-style' with "):
        planned_runs(load_plan(plan), tmp_path / "out", 1000, "serial")  # at most 256 workers


def test_a_plans_figure_cases_are_the_papers() -> None:
    from typing import get_args

    from skyvln_eval.control import PAPER_CASES
    from skyvln_eval.harness.plan import PaperCase

    assert set(get_args(PaperCase)) == set(PAPER_CASES)


def test_reproduce_data_dir_dot_sample_is_the_folder_not_the_synthetic_sample(
    tmp_path: Path, cli: Cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit: --data-dir was a Path, which drops the "./": ./sample became "sample".
    from skyvln_eval.harness import reproduce as reproduce_module

    given: list[str | None] = []

    def recorded(plan: Any, out: Path, workers: int, executor: str, data: str | None,
                 *args: Any, **kwargs: Any) -> Any:  # fmt: skip
        given.append(data)
        raise ConfigError("stopped here")

    monkeypatch.setattr(reproduce_module, "reproduce", recorded)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sample").mkdir()
    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(TINY_PLAN))
    _refused(cli("reproduce", "--plan", "plan.yaml", "--data-dir", "./sample"), "stopped here")
    assert given == ["./sample"]
