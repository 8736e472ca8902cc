"""Reproduce: a small plan writes both tables, the figures and a summary, and resumes."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from skyvln_eval.cli import app
from skyvln_eval.configs import config_path
from skyvln_eval.errors import ConfigError
from skyvln_eval.harness import plan as plan_module
from skyvln_eval.harness.plan import environment_backends, load_plan, planned_runs, slug
from skyvln_eval.harness.reproduce import CONTROL_COLUMNS, WALL_CLOCK_METRICS, reproduce
from skyvln_eval.harness.run import CONFIG_FILE
from skyvln_eval.llm import LLMConfig
from skyvln_eval.metrics.scores_io import read_scores

TINY_PLAN = {
    "name": "tiny",
    "limit": 1,
    "resamples": 50,
    "dynamics": {"controller_settings": {"compile": "never"}},
    "table1": {
        "splits": ["val_unseen", "test_unseen"],
        "systems": [
            {"label": "NavGPT-style", "mode": "official", "agent": {"name": "navgpt"}},
            {
                "label": "Full",
                "mode": "dynamics",
                "controller": "nmpc",
                "agent": {"name": "skyvln"},
            },
        ],
    },
    "table2": {
        "split": "test_unseen",
        "system": {
            "label": "Full",
            "mode": "dynamics",
            "controller": "nmpc",
            "agent": {"name": "skyvln"},
        },
        "backends": [
            {"label": "rule-based (not an LLM)", "llm": {"backend": "rule"}},
            {"label": "random (not an LLM)", "llm": {"backend": "random"}},
        ],
        "environment_variable": None,
    },
    "control_figures": {"controllers": ["pid"], "cases": ["static"]},
    "trajectory_figures": 1,
}


def write_plan(path: Path, data: str) -> Path:
    path.write_text(yaml.safe_dump(TINY_PLAN | {"data": data}))
    return path


def test_a_small_plan_writes_tables_figures_and_summary_and_resumes(
    tmp_path: Path, sample_dir: Path
) -> None:
    plan = load_plan(write_plan(tmp_path / "tiny.yaml", str(sample_dir)))
    runs = planned_runs(plan, tmp_path / "out", 1, "serial")
    # The rule-backend row of Table II is the Full system of Table I: one run, two rows.
    assert len(runs) == 5
    assert any(len(r.rows) == 2 for r in runs)
    report = reproduce(plan, tmp_path / "out", workers=1, executor="serial")
    assert report.complete
    for name in (
        "table1.md",
        "table1.tex",
        "table1.csv",
        "table2.md",
        "table2.tex",
        "table1_ci.md",
        "control.md",
        "cost.md",
        "control_static.png",
        "sr_vs_threshold.png",
        "ne_distribution.png",
        "SUMMARY.md",
        "scores.csv",
        "summary.csv",
    ):
        assert report.files[name].is_file(), name
    table1 = report.files["table1.md"].read_text()
    assert "NavGPT-style" in table1 and "Full" in table1 and "Unseen Testing" in table1
    table2 = report.files["table2.md"].read_text()
    assert "rule-based (not an LLM)" in table2 and "random (not an LLM)" in table2
    assert "\\toprule" in report.files["table1.tex"].read_text()
    # Every control column the table asks for is in the scores (none silently dropped), and
    # each header says how the episodes combine.
    control = report.files["control.md"].read_text().splitlines()
    header = [cell.strip() for cell in control[2].strip("|").split("|")]
    assert len(header) == 2 + len(CONTROL_COLUMNS), header
    assert (
        "min keep-out clearance/m, worst episode" in header and "Keep-out clearance" in control[-1]
    )
    full = next(line for line in control if line.startswith("| Full"))
    assert "-" not in full.split("|")[3:]  # a flown system has every control figure
    # Table II's backends flew too (its system is a dynamics one): their rows are there,
    # of their one split, as the note says.
    rows = [line.split("|")[1].strip() for line in control if line.startswith("| ")]
    assert rows[1:] == ["Full †", "rule-based (not an LLM)", "random (not an LLM)"], rows
    assert (
        "Table II's (rule-based (not an LLM), random (not an LLM)) are of test_unseen"
        in (control[-1])
    )
    assert any(name.startswith("trajectory_") for name in report.files)
    summary = report.files["SUMMARY.md"].read_text()
    assert "Table I" in summary and "Table II" in summary and "control_static.png" in summary
    # The page names the wall-clock columns (the only values that vary between runs of the
    # same seed): each is a column of the scores, so the page names nothing that is not there.
    scores_header = report.files["scores.csv"].read_text().splitlines()
    columns = next(line for line in scores_header if not line.startswith("#")).split(",")
    assert set(WALL_CLOCK_METRICS) <= set(columns)
    assert all(f"`{metric}`" in summary for metric in WALL_CLOCK_METRICS)
    assert "Every other value of the scores, tables and figures is byte-identical" in summary
    assert "solve-time columns are measured wall-clock times" in control[-1]
    cost = report.files["cost.md"].read_text().strip().splitlines()
    assert "llm_latency_s and wall_s are measured wall-clock times" in cost[-1]
    assert "not an LLM" in summary
    # Every file reproduce wrote is linked from the page ("SUMMARY.md, which links everything").
    for name, path in report.files.items():
        if name != "SUMMARY.md":
            assert f"]({path.relative_to(tmp_path / 'out').as_posix()})" in summary, name
    assert {"table2_ci.md", "tables.json", "dataset_summary.json"} <= set(report.files)
    summarised = json.loads(report.files["dataset_summary.json"].read_text())
    assert summarised["data"] == plan.data and "data_dir" not in summarised  # as named
    assert any(name.startswith("control_runs/") for name in report.files)
    # The scored rows outnumber the episodes by the shared run's, and the page says why.
    shared = "Full † (Table I) and rule-based (not an LLM) (Table II) are one run"
    scored_rows = len(read_scores(report.files["scores.csv"])[0])
    episodes = sum(len(r.expected) for r in report.reports)
    assert scored_rows == episodes + 1  # limit 1: the shared run's one episode, twice
    assert (
        f"{scored_rows} scored episode rows for {episodes} episodes: {shared} "
        "(test_unseen: 1 episode), scored once for each row" in summary
    )
    # The Runs table names each run by the rows it fills, labelled as the tables label them.
    runs = summary.split("## Runs", 1)[1].split("## Dataset", 1)[0]
    assert "| Full † (Table I), rule-based (not an LLM) (Table II) | test_unseen |" in runs
    labels = {f"| {row} |" for r in report.run_rows for _, row in r}
    tables_text = table1 + table2
    assert labels and all(label in tables_text for label in labels), labels
    recordings = sorted(name for name in report.files if name.endswith(".rrd"))
    if importlib.util.find_spec("rerun") is not None:
        # One recording per system (limit 1): NavGPT-style, Full (also Table II's rule row),
        # random; linked from the summary with the command that opens them.
        assert [name.split("__")[0] for name in recordings] == [
            "full",
            "navgpt-style",
            "random-not-an-llm",
        ]
        assert all(report.files[name].stat().st_size > 10_000 for name in recordings)
        assert (
            f"(recordings/{recordings[0]})" in summary and "skyvln-eval view recordings/" in summary
        )
    else:
        assert not recordings and "pip install 'skyvln-eval[viewer]'" in summary

    # `table` on the scores reproduce wrote makes the files it wrote (its tables.json says
    # which rows, in which order, with which notes), in every format and with intervals.
    scores = str(report.files["scores.csv"])
    for kind, fmt, name, extra in (
        ("table1", "md", "table1.md", []),
        ("table1", "latex", "table1.tex", []),
        ("table1", "csv", "table1.csv", []),
        ("table1", "md", "table1_ci.md", ["--ci"]),
        ("table2", "md", "table2.md", []),
        ("table2", "md", "table2_ci.md", ["--ci"]),
    ):
        made = CliRunner().invoke(app, ["table", scores, "--kind", kind, "--format", fmt, *extra])
        assert made.exit_code == 0, made.output
        assert made.output == report.files[name].read_text(), name
    again = reproduce(plan, tmp_path / "out", workers=1, executor="serial")
    assert all(r.ran_now == 0 for r in again.reports)
    assert again.files["table1.md"].read_text() == table1  # same results, same table
    page = again.files["SUMMARY.md"].read_text()  # no "0 s of wall time for 0 s of flight"
    assert "nothing was left to run: every episode was recorded before" in page
    assert "episode(s) run now took" in summary


def test_reproduce_command_on_a_small_plan(tmp_path: Path, sample_dir: Path) -> None:
    # "sample" is the session's cached sample_dir ($SKYVLN_EVAL_CACHE).
    plan = write_plan(tmp_path / "tiny.yaml", "sample")
    result = CliRunner().invoke(
        app,
        [
            "reproduce",
            "--plan",
            str(plan),
            "--out",
            str(tmp_path / "cli"),
            "--workers",
            "1",
            "--executor",
            "serial",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "NavGPT-style" in result.output and (tmp_path / "cli" / "SUMMARY.md").is_file()
    # Its runs name the synthetic set, not where this machine's cache keeps it: an output
    # folder is the same, and resumes, wherever it is made.
    configs = sorted((tmp_path / "cli" / "runs").rglob(CONFIG_FILE))
    assert configs and all(yaml.safe_load(path.read_text())["data"] == "sample" for path in configs)
    assert str(sample_dir) not in "".join(path.read_text() for path in configs)


def test_the_default_plan_has_the_papers_rows() -> None:
    plan = load_plan("default")
    assert [s.label for s in plan.table1.systems] == [
        "Random",
        "NavGPT-style",
        "w PID",
        "w MPC",
        "w NMPC",
        "w/o HSD",
        "w/o TMA",
        "Full",
        "GT replay (oracle)",
    ]
    assert plan.table1.splits == ("val_seen", "val_unseen", "test_unseen")
    labels = [b.label for b in plan.table2.backends]
    assert labels == ["rule-based (not an LLM)", "random (not an LLM)"]


def test_the_readme_lists_the_default_plans_rows_and_every_output() -> None:
    readme = (Path(__file__).parents[2] / "README.md").read_text()
    outputs = readme.split("writes under `reproduce-output/`:\n\n", 1)[1].split("\n\n", 1)[0]
    table1 = outputs.split("Table I (", 1)[1].split("over seen validation", 1)[0]
    for system in load_plan("default").table1.systems:
        assert system.label in table1, system.label
    for output in ("tables/table1", "tables/table2", "figures/", "control_runs/", "scores/",
                   "summary.csv", "tables.json", "runs/", "recordings/", "dataset_summary.json",
                   "SUMMARY.md"):  # fmt: skip
        assert f"`{output}" in outputs, output


def test_a_system_can_override_its_controller_settings(tmp_path: Path) -> None:
    plan = load_plan("default")
    systems = list(plan.table1.systems)
    mpc = next(k for k, s in enumerate(systems) if s.label == "w MPC")
    blind = systems[mpc].model_copy(
        update={"label": "w MPC, no obstacles", "controller_settings": {"max_obstacles": 0}}
    )
    plan = plan.model_copy(
        update={"table1": plan.table1.model_copy(update={"systems": (*systems, blind)})}
    )
    runs = {r.rows[0][1]: r.config for r in planned_runs(plan, tmp_path, 1, "processes")}
    assert runs["w MPC, no obstacles"].dynamics.controller_settings == {"max_obstacles": 0}
    assert runs["w MPC"].dynamics.controller_settings == {}
    # Different settings are different runs, never merged into one.
    assert runs["w MPC, no obstacles"].digest() != runs["w MPC"].digest()


def test_the_default_plan_takes_three_obstacles_with_three_slots_per_mpc(tmp_path: Path) -> None:
    # An audit: following the error's advice was refused, the plan's dynamics checked
    # against a controller no system flies (with max_obstacles set per system), or the
    # PID row given an MPC's setting (set for the plan).
    data = yaml.safe_load(config_path("reproduce", "default.yaml").read_text())
    data["dynamics"]["obstacles"] = {"n_obstacles": 3}
    slots = {"mpc", "nmpc"}
    for system in [*data["table1"]["systems"], data["table2"]["system"]]:
        if system.get("mode") == "dynamics" and system.get("controller", "nmpc") in slots:
            system["controller_settings"] = {"max_obstacles": 3}
    path = tmp_path / "three.yaml"
    path.write_text(yaml.safe_dump(data))
    runs = [r.config for r in planned_runs(load_plan(path), tmp_path / "out", 1, "serial")]
    flown = [c for c in runs if c.mode == "dynamics"]
    assert {c.dynamics.obstacles.n_obstacles for c in flown} == {3}
    pid = next(c for c in flown if c.dynamics.controller == "pid")
    assert pid.dynamics.controller_settings == {"max_speed_m_s": 15.0}
    # Left at two slots, the MPC row is named, with what to set.
    data["table1"]["systems"][3]["controller_settings"] = {}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as refused:
        load_plan(path)
    assert str(refused.value).startswith(
        f"reproduce plan {path}: table1.systems.3: system 'w MPC' flying mpc with the plan's "
        "settings: dynamics: controller 'mpc' plans around its 2 nearest obstacles"
    )
    assert "Set controller_settings: {max_obstacles: 3}" in str(refused.value)


def test_a_plan_can_leave_the_images_out_of_its_run_logs(tmp_path: Path) -> None:
    default = planned_runs(load_plan("default"), tmp_path, 1, "processes")
    assert all(r.config.observations_in_logs for r in default)
    lean = load_plan("default", observations_in_logs=False)
    assert not any(
        r.config.observations_in_logs for r in planned_runs(lean, tmp_path, 1, "processes")
    )


def test_endpoints_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(
        "SKYVLN_TEST_BACKENDS", "openai:gpt-4o, openai:llama3@http://127.0.0.1:11434/v1"
    )
    backends = environment_backends("SKYVLN_TEST_BACKENDS")
    assert [b.llm["backend"] for b in backends] == ["openai:gpt-4o", "openai:llama3"]
    assert backends[1].llm["base_url"] == "http://127.0.0.1:11434/v1"
    # Read as a run config reads it: '@' in a model id is the id's, the server follows
    # the last '@' (the entry used to be cut at the first, the id's, giving no server).
    monkeypatch.setenv(
        "SKYVLN_TEST_BACKENDS", "openai:m@2024, openai:m@2024@http://127.0.0.1:11434/v1"
    )
    bare, served = environment_backends("SKYVLN_TEST_BACKENDS")
    assert (bare.llm["backend"], bare.llm.get("base_url"), bare.label) == (
        "openai:m@2024",
        None,
        "m@2024",
    )
    assert (served.llm["backend"], served.llm["base_url"]) == (
        "openai:m@2024",
        "http://127.0.0.1:11434/v1",
    )
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "gpt-4o")
    with pytest.raises(ConfigError, match="SKYVLN_TEST_BACKENDS"):
        environment_backends("SKYVLN_TEST_BACKENDS")
    assert slug("w/o HSD") == "w-o-hsd"


def test_every_way_of_naming_a_backend_gives_its_full_configuration(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    backends = tmp_path / "backends.yaml"
    backends.write_text(
        yaml.safe_dump(
            {
                "format": "skyvln-eval/llm-backends",
                "version": 1,
                "defaults": {"timeout_s": 120.0, "max_concurrency": 8, "api_key_env": "MY_KEY"},
                "backends": {
                    "local-gemma": {
                        "backend": "openai:gemma-3-270m",
                        "base_url": "http://127.0.0.1:8765/v1",
                        "structured_output": "json_object_schema",
                        "takes_images": True,
                    },
                    # The toolkit's defaults, said outright: kept over the plan system's.
                    "as-default": {
                        "backend": "openai:m",
                        "base_url": "http://127.0.0.1:8766/v1",
                        "timeout_s": 60.0,
                        "structured_output": "auto",
                        "max_concurrency": 4,
                        "takes_images": False,
                    },
                },
            }
        )
    )
    monkeypatch.setenv("SKYVLN_EVAL_BACKENDS_FILE", str(backends))
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "local-gemma, openai:gpt-4o-mini")
    monkeypatch.setenv("MY_KEY", "sk-test")  # OpenAI's server: a plan without it is refused
    named, spec = environment_backends("SKYVLN_TEST_BACKENDS")
    assert named.label == "local-gemma" and spec.label == "gpt-4o-mini"
    gemma = LLMConfig.model_validate(named.llm)
    assert (gemma.structured_output, gemma.takes_images) == ("json_object_schema", True)
    mini = LLMConfig.model_validate(spec.llm)  # a bare spec gets the file's defaults
    assert (mini.timeout_s, mini.max_concurrency, mini.api_key_env) == (120.0, 8, "MY_KEY")
    assert (gemma.timeout_s, gemma.max_concurrency) == (120.0, 8)
    # In a plan, a remote model gets a response cache beside the outputs.
    plan = load_plan("default").model_copy()
    plan = plan.model_copy(
        update={
            "table2": plan.table2.model_copy(
                update={"environment_variable": "SKYVLN_TEST_BACKENDS"}
            )
        }
    )
    runs = {
        label: r.config for r in planned_runs(plan, tmp_path, 1, "threads") for _, label in r.rows
    }
    assert runs["local-gemma"].agent.llm.cache_path == str(tmp_path / "llm-cache.sqlite")
    assert runs["local-gemma"].agent.llm.base_url == "http://127.0.0.1:8765/v1"
    # An entry's values equal to the defaults are its own too (an audit: they gave way to
    # the plan system's, while the same entry listed in the plan kept them).
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "as-default")
    system = plan.table2.system
    chosen = {"timeout_s": 300.0, "structured_output": "prompt", "max_concurrency": 1}
    agent = {**system.agent, "llm": {"backend": "rule", "takes_images": True, **chosen}}
    table2 = plan.table2.model_copy(update={"system": system.model_copy(update={"agent": agent})})
    (named,) = [
        r.config.agent.llm
        for r in planned_runs(plan.model_copy(update={"table2": table2}), tmp_path, 1, "threads")
        if ("table2", "as-default") in r.rows
    ]
    assert named is not None
    assert (named.timeout_s, named.structured_output, named.max_concurrency) == (60.0, "auto", 4)
    assert named.takes_images is False
    # A replay of a model reads the answers from that same cache (a replay without a cache
    # is refused on load).
    replayed = plan_module._kept_answers({"backend": "replay:openai:gpt-4o-mini"}, tmp_path)
    assert LLMConfig.model_validate(replayed).cache_path == str(tmp_path / "llm-cache.sqlite")
    # The local-llm plan's relative cache_path lands inside --out (an audit found it in the
    # working directory), for Table I's model rows as for Table II's.
    local = [r.config for r in planned_runs(load_plan("local-llm"), tmp_path, 1, "threads")]
    caches = {c.agent.llm.cache_path for c in local if c.agent.llm is not None}
    assert caches - {None} == {str(tmp_path / "local-llm-cache.sqlite")}
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", "local-gema")
    with pytest.raises(ConfigError, match="Did you mean 'local-gemma'"):
        environment_backends("SKYVLN_TEST_BACKENDS")
    backends.write_text(
        "format: skyvln-eval/llm-backends\nversion: 1\nbackends: {x: {tmeout_s: 1}}\n"
    )
    with pytest.raises(ConfigError, match=r"backends\.yaml: x: tmeout_s"):
        environment_backends("SKYVLN_TEST_BACKENDS")


def test_cost_md_tells_small_costs_apart() -> None:
    # From an audit: 3 decimals showed 0.0014 and 0.0006 (USD per episode) both as 0.001.
    import pandas as pd

    from skyvln_eval.harness.reproduce import COST_METRICS, _metric_table

    scores = pd.DataFrame(
        {
            "system": ["a", "a", "b"],
            "llm_cost_usd": [0.0014, 0.0014, 0.0006],
            "llm_cost_lower_usd": [0.0014, 0.0014, 0.0006],
            "llm_latency_s": [1.23456, 1.23456, 2.0],
        }
    )
    columns = [(metric, metric, "mean") for metric in COST_METRICS]
    table = _metric_table(scores, ["a", "b"], columns, "cost")
    assert "| a | 2 | 0.001400 | 0.001400 | 1.235 |" in table
    assert "| b | 1 | 0.000600 | 0.000600 | 2.000 |" in table


def test_control_md_counts_the_episodes_that_flew() -> None:
    # From an audit: an episode that ended before any flight counted in "episodes" while
    # every cell averaged the flown ones only.
    import pandas as pd

    from skyvln_eval.harness.reproduce import CONTROL_COLUMNS, _metric_table

    scores = pd.DataFrame(
        {
            "system": ["a", "a", "a", "b"],
            "has_control": [True, True, False, True],
            "solve_failures": [2.0, 0.0, None, 1.0],
        }
    )
    table = _metric_table(scores, ["a", "b"], CONTROL_COLUMNS, "control", counted="has_control")
    assert "| a | 2 of 3 | 1.000 |" in table and "| b | 1 | 1.000 |" in table
    assert "| a | 3 | 1.000 |" in _metric_table(scores, ["a"], CONTROL_COLUMNS, "control")


def test_the_oracle_is_marked_in_every_row_label_reproduce_writes() -> None:
    # An audit: an oracle flown in dynamics mode was marked in Table I (at render time) but
    # not in control.md or SUMMARY.md's run list, which take their labels from here.
    from skyvln_eval.agent.config import AgentConfig
    from skyvln_eval.harness.reproduce import table1_label

    oracle = AgentConfig.model_validate({"name": "ground_truth"})
    assert table1_label("Route follower", oracle) == ("Route follower (oracle)", None)
    assert table1_label("GT replay (oracle)", oracle) == ("GT replay (oracle)", None)
    random = AgentConfig.model_validate({"name": "random"})
    assert table1_label("Random", random) == ("Random", None)
