"""Runs: results and run MCAPs, resume, worker-count independence, faults, Ray."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from skyvln_eval.agent.base import episode_key
from skyvln_eval.avdn import load_split, view_centre
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import read_episode, read_log
from skyvln_eval.converters.validate import check_log
from skyvln_eval.errors import ConfigError, IncompleteRunError, ResultRecordError
from skyvln_eval.harness import RunConfig, load_run_config, make_executor, run, run_results
from skyvln_eval.harness.config import run_config_from_mapping
from skyvln_eval.harness.run import error_verdict
from skyvln_eval.harness.store import RESULTS_FILE
from skyvln_eval.metrics import MetricConventions, read_control_log, read_results, score_results
from tests.conftest import REPO
from tests.harness.compare import comparable, scores_of

MakeConfig = Callable[..., RunConfig]


def test_official_run_writes_results_and_run_logs_then_resumes_nothing(
    tmp_path: Path, small_config: MakeConfig, sample_dir: Path
) -> None:
    config = small_config(splits=("val_seen", "val_unseen"))
    run_dir = tmp_path / "run"
    report = run(config, run_dir)
    assert report.complete and report.ran_now == 4 and not report.errors
    results = read_results(run_dir / RESULTS_FILE)
    assert [r.split for r in results].count("val_seen") == 2
    assert all(
        r.status == "ok" and r.system == "test system" and len(r.visited_views) >= 1
        for r in results
    )
    assert all(r.extra["execution_mode"] == "official" and r.llm_calls for r in results)
    for name in ("config.yaml", "versions.json", "run.json"):
        assert (run_dir / name).is_file()

    episodes = {e.episode_id: e for e in load_split(sample_dir, "val_unseen").episodes()}
    result = next(r for r in results if r.split == "val_unseen")
    log_path = run_dir / "logs" / "val_unseen" / f"{result.episode_id}.mcap"
    assert read_episode(log_path) == episodes[result.episode_id]  # the run log holds the episode
    check = check_log(log_path)
    assert not check.issues, check.issues  # every message valid against its channel's schema
    log = read_log(log_path)
    steps = [m.decode() for m in log.topic(t.TOPIC_AGENT_STEP)]
    assert len(steps) == int(result.extra["actions"])
    assert steps[0]["trace"]["subgoals"]
    # A fix per decision at its view's centre, as an episode log has (one Map layout for both).
    fixes = [m.decode() for m in log.topic(t.TOPIC_GPS)]
    assert len(fixes) == len(steps)
    start = view_centre(np.asarray(episodes[result.episode_id].start_view)[None])[0]
    assert (fixes[0]["latitude"], fixes[0]["longitude"]) == tuple(start)
    assert log.topic(t.TOPIC_LLM_EXCHANGE) and log.topic(t.TOPIC_RUN_VIEWS)
    assert log.metadata[t.RUN_METADATA]["system"] == "test system"

    # An official step's second is nominal: no "x real time" claim (nor on resume).
    first = json.loads((run_dir / "run.json").read_text())
    assert first["simulated_s"] == 0.0
    again = run(config, run_dir)
    assert again.ran_now == 0 and again.already_done == 4
    assert len(read_results(run_dir / RESULTS_FILE)) == 4
    with pytest.raises(ConfigError, match="another configuration") as refused:
        run(small_config(splits=("val_seen", "val_unseen"), max_action_len=3), run_dir)
    assert "max_action_len 10 here, 3 given" in str(refused.value)  # says what differs
    # A quick look grows in place into a larger one, its episodes kept; it never shrinks.
    grown = config.model_copy(update={"limit": 3})
    more = run(grown, run_dir)
    assert (more.ran_now, more.already_done, more.complete) == (2, 4, True)
    assert len(read_results(run_dir / RESULTS_FILE)) == 6
    assert "limit: 3" in (run_dir / "config.yaml").read_text()
    with pytest.raises(ConfigError, match="may only grow"):
        run(config, run_dir)


def test_the_results_of_a_run_from_python_are_all_of_its_episodes_or_refused(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    run_dir = tmp_path / "run"
    run(small_config(write_logs=False), run_dir)
    assert len(run_results(run_dir)) == 2
    # A run still going (or stopped) is not read as a finished one: half a run's mean
    # would pass for the run's.
    results = run_dir / RESULTS_FILE
    lines = results.read_text().splitlines(keepends=True)
    results.write_text("".join(lines[:-1]))
    with pytest.raises(IncompleteRunError, match=r"1 recorded\).*1 missing episode"):
        run_results(run_dir)
    assert len(run_results(run_dir, allow_incomplete=True)) == 1


def test_dynamics_run_flies_with_a_controller_and_logs_it(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    config = small_config(mode="dynamics", limit=1, dynamics={"controller": "nmpc"})
    run_dir = tmp_path / "dyn"
    report = run(config, run_dir)
    assert report.complete and not report.errors
    (result,) = read_results(run_dir / RESULTS_FILE)
    assert result.control is not None and result.control.steps > 50
    assert result.control.controller == "nmpc" and result.control.scenario == "crossing"
    assert result.control_log is not None and (run_dir / result.control_log).is_file()
    # How it was flown goes with the log (an audit found only the controller's name):
    # the controller as built (horizon, limits, which QP solver ran) and the flight's.
    flown_with = read_control_log(run_dir / result.control_log).attrs["settings"]
    built = flown_with["controller_settings"]
    assert (built["name"], built["horizon_steps"], built["dt_s"]) == ("nmpc", 20, 0.1)
    assert built["qp_solver_used"] in ("riccati", "hpipm") and "compiled" in built
    assert flown_with["flight"]["cruise_speed_m_s"] == config.dynamics.cruise_speed_m_s
    assert result.extra["simulated_s"] > 5.0
    assert report.simulated_s == result.extra["simulated_s"]  # flown now
    assert run(config, run_dir).simulated_s == 0.0  # nothing flown on resume
    log = read_log(run_dir / "logs" / "val_unseen" / f"{result.episode_id}.mcap")
    assert len(log.topic(t.TOPIC_CONTROL_STEP)) == result.control.steps
    assert log.topic(t.TOPIC_OBSTACLES) and log.topic(t.TOPIC_AGENT_TARGET)
    # An audit: the airframe's roll and pitch were in /control/step only, and the drone's
    # last place (after its last control step) was on /run/path but in no /tf nor fix.
    transforms = [m.decode() for m in log.topic(t.TOPIC_TF)]
    body = [m for m in transforms if m["child_frame_id"] == t.BODY_FRAME]
    assert len(body) == result.control.steps
    assert any(abs(m["rotation"]["x"]) + abs(m["rotation"]["y"]) > 1e-3 for m in body)
    drone = [m for m in transforms if m["child_frame_id"] == t.DRONE_FRAME]
    assert all(m["rotation"]["x"] == m["rotation"]["y"] == 0.0 for m in drone)  # level
    last_view = log.topic(t.TOPIC_RUN_PATH)[-1].log_time_ns
    for topic in (t.TOPIC_TF, t.TOPIC_GPS):
        assert max(m.log_time_ns for m in log.topic(topic)) == last_view, topic
    assert not check_log(run_dir / "logs" / "val_unseen" / f"{result.episode_id}.mcap").issues


def test_a_flight_whose_controller_fell_back_is_degraded_not_ok(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # A slack this dear makes the QP infeasible whenever an obstacle is near: the controller
    # falls back (hover, shifted plan) on those steps. The flight is not the controller's.
    dear = {"compile": "never", "weights": {"slack_linear": 1e12, "slack_quadratic": 1e12}}
    config = small_config(
        mode="dynamics", limit=1, dynamics={"controller": "nmpc", "controller_settings": dear}
    )
    report = run(config, tmp_path / "dyn")
    (result,) = read_results(tmp_path / "dyn" / RESULTS_FILE)
    assert result.control is not None and result.control.solve_failures > 0
    assert result.status == "degraded" and report.statuses == {"degraded": 1}


def test_controller_limits_beyond_the_drone_are_refused(small_config: MakeConfig) -> None:
    wide = {"limits": {"tilt_ref_max_rad": 0.8}}
    with pytest.raises(ValidationError, match=r"0\.8 goes beyond the simulated drone.s 0\.436"):
        small_config(mode="dynamics", dynamics={"controller": "nmpc", "controller_settings": wide})
    data = {"system": "s", "data": "sample", "mode": "dynamics"}
    data["dynamics"] = {"controller_settings": wide}
    with pytest.raises(ConfigError, match=r"run\.yaml.*controller_settings\.limits\.tilt_ref_max"):
        run_config_from_mapping(data, "run.yaml")  # as a file's config is read: the field named
    narrow = {"limits": {"tilt_ref_max_rad": 0.3}}  # within the drone's: the planner's choice
    small_config(mode="dynamics", dynamics={"controller": "nmpc", "controller_settings": narrow})


@pytest.mark.parametrize("mode", ["official", "dynamics"])
def test_one_and_two_workers_give_identical_results(
    tmp_path: Path, small_config: MakeConfig, mode: str
) -> None:
    serial = run(
        small_config(mode=mode, limit=2, splits=("val_unseen", "test_unseen")), tmp_path / "one"
    )
    config = small_config(
        mode=mode, limit=2, splits=("val_unseen", "test_unseen"), workers=2, executor="processes"
    )
    parallel = run(config, tmp_path / "two")
    assert serial.complete and parallel.complete
    one = sorted(read_results(tmp_path / "one" / RESULTS_FILE), key=lambda r: r.key)
    two = sorted(read_results(tmp_path / "two" / RESULTS_FILE), key=lambda r: r.key)
    assert [comparable(r) for r in one] == [comparable(r) for r in two]
    assert scores_of(one) == scores_of(two)
    # The logs' run metadata too (their messages hold call latencies): it recorded the
    # executor and the worker count.
    logs = sorted(p.relative_to(tmp_path / "one") for p in (tmp_path / "one").rglob("*.mcap"))
    assert len(logs) == 4
    for log in logs:
        one_meta, two_meta = (
            read_log(tmp_path / folder / log).metadata[t.RUN_METADATA] for folder in ("one", "two")
        )
        assert one_meta == two_meta, log
        assert "executor" not in one_meta["config"] and "limit" not in one_meta["config"]


def test_an_agent_that_raises_marks_its_episode_error_and_the_run_goes_on(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    from skyvln_eval.harness import runner

    real_build = runner.build_agent
    victim: list[str] = []

    def build(config: Any, *args: Any) -> Any:
        agent = real_build(config, *args)
        act = agent.act

        def act_or_raise(observation: Any) -> Any:
            if agent._episode_key_for_test == episode_key(victim[0]):  # type: ignore[attr-defined]
                raise RuntimeError("agent exploded")
            return act(observation)

        reset = agent.reset

        def reset_and_remember(brief: Any) -> None:
            agent._episode_key_for_test = brief.episode_key  # type: ignore[attr-defined]
            reset(brief)

        agent.act, agent.reset = act_or_raise, reset_and_remember  # type: ignore[method-assign]
        return agent

    monkeypatch.setattr(runner, "build_agent", build)
    config = small_config(limit=3)
    victim.append(load_split(config.data, "val_unseen").records[1].episode_id)
    report = run(config, tmp_path / "run")
    assert report.complete
    assert list(report.errors) == [("val_unseen", victim[0])]
    assert "RuntimeError: agent exploded" in report.errors[("val_unseen", victim[0])]
    results = {r.episode_id: r for r in read_results(tmp_path / "run" / RESULTS_FILE)}
    assert results[victim[0]].status == "error" and "Traceback" in (results[victim[0]].error or "")
    assert sum(r.status == "ok" for r in results.values()) == 2
    scores = score_results(list(results.values()), MetricConventions()).set_index("episode_id")
    assert scores.loc[victim[0], "success"] == 0.0  # a failure counts, it is not dropped


def test_an_llm_server_that_fails_leaves_error_episodes_with_the_faults_recorded(
    tmp_path: Path, small_config: MakeConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    from skyvln_eval.llm.loopback import LoopbackOpenAIServer, status

    with LoopbackOpenAIServer([status(500) for _ in range(400)]) as server:
        llm = {
            "backend": "openai:broken-model",
            "base_url": server.base_url,
            "api_key_env": "SKYVLN_TEST_KEY",
            "retry": {"max_attempts": 2, "initial_delay_s": 0.0},
        }
        monkeypatch.setenv("SKYVLN_TEST_KEY", "sk-test")
        config = small_config(limit=2, agent={"name": "skyvln", "llm": llm})
        report = run(config, tmp_path / "run")
    assert report.complete and not report.missing
    results = read_results(tmp_path / "run" / RESULTS_FILE)
    assert len(results) == 2
    for result in results:
        errors = [c.error for c in result.llm_calls if c.error]
        assert errors and all("HTTP 500" in e for e in errors), "every fault must be recorded"
        # No call was answered: the episode is an error, not a result that looks normal.
        assert result.status == "error" and "no LLM call" in (result.error or "")
        assert result.fallback_decisions == result.decisions >= 1
        # The run log says so too, with the counts behind it (the viewer's episode card).
        log = read_log(tmp_path / "run" / "logs" / result.split / f"{result.episode_id}.mcap")
        meta = log.metadata[t.RUN_METADATA]
        finals = [c for c in result.llm_calls if c.final]
        assert meta["status"] == "error" and meta["llm_calls"] == str(len(finals))
        assert meta["llm_failed_calls"] == str(sum(c.outcome == "failed" for c in finals)) != "0"
        assert meta["fallback_decisions"] == str(result.fallback_decisions)
    assert report.statuses == {"error": 2} and len(report.errors) == 2
    verdict = error_verdict([report], fail_on_error=0.0)
    assert verdict is not None and "2 of 2 episode(s) ended in error" in verdict
    assert "HTTP 500" in verdict  # the first error text of its kind
    assert f"--out {report.run_dir} --retry-failed" in verdict  # and how to run them again
    assert error_verdict([report], fail_on_error=1.0) is None


def test_ray_executor_matches_the_local_one(tmp_path: Path, small_config: MakeConfig) -> None:
    pytest.importorskip(
        "ray", reason="the ray extra is not installed: pip install 'skyvln-eval[ray]'"
    )
    local = run(small_config(limit=2), tmp_path / "local")
    remote = run(small_config(limit=2), tmp_path / "ray", executor=make_executor("ray", 2))
    assert local.complete and remote.complete and not remote.errors
    assert scores_of(read_results(tmp_path / "ray" / RESULTS_FILE)) == scores_of(
        read_results(tmp_path / "local" / RESULTS_FILE)
    )


def test_run_configs_are_validated_with_the_field_named(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("system: x\nmode: flying\nagent: {hsd: maybe}\n")
    with pytest.raises(ConfigError) as info:
        load_run_config(path)
    assert (
        "mode" in str(info.value)
        and "agent.hsd" in str(info.value)
        and "bad.yaml" in str(info.value)
    )
    path.write_text("system: x\nworkerz: 3\n")
    with pytest.raises(ConfigError, match="workerz"):
        load_run_config(path)
    for shipped in sorted((REPO / "skyvln_eval" / "configs" / "runs").glob("*.yaml")):
        assert load_run_config(shipped).system


def test_listed_episodes_past_the_limit_are_found_and_cut_by_it(
    sample_dir: Path, small_config: MakeConfig
) -> None:
    from skyvln_eval.harness.run import episode_logs

    ids = [e.episode_id for e in load_split(sample_dir, "val_unseen").episodes()][:3]
    logs = episode_logs(small_config(episodes=ids, limit=1), sample_dir)
    assert list(logs) == [("val_unseen", ids[0])]  # was: 'episodes not found' for the other two
    unknown = r"the run config's episodes: not found in split\(s\) val_unseen of .*: nope"
    with pytest.raises(ConfigError, match=unknown):
        episode_logs(small_config(episodes=[*ids, "nope"], limit=1), sample_dir)


def test_a_run_grows_in_place_only_to_a_selection_holding_its_episodes(
    small_config: MakeConfig,
) -> None:
    from skyvln_eval.harness.run import grows

    base = small_config(limit=2)
    assert grows(base, small_config(limit=5)) and grows(base, small_config(limit=None))
    assert not grows(base, small_config(limit=1))
    assert not grows(base, small_config(limit=5, max_action_len=3))  # another setting too
    listed = small_config(limit=None, episodes=["a", "b"])
    assert grows(listed, small_config(limit=None, episodes=["b", "a", "c"]))
    assert grows(listed, small_config(limit=None))
    assert not grows(listed, small_config(limit=None, episodes=["a"]))
    # A limit as well: the first one of the longer list may not be one of the shorter's.
    assert not grows(listed, small_config(limit=1, episodes=["a", "b", "c"]))
    assert not grows(small_config(limit=None), small_config(limit=None, episodes=["a"]))


def test_rows_another_configuration_made_are_refused_by_resume_and_score(
    tmp_path: Path, small_config: MakeConfig, cli: Any
) -> None:
    # An audit resumed a run whose config.yaml was replaced by another system's: "24
    # already done", rows of the old system scored under the new config; and a row copied
    # in from another run was scored as this one's.
    from skyvln_eval.harness.run import foreign_rows

    config = small_config(limit=1)
    run_dir = tmp_path / "run"
    assert run(config, run_dir).complete
    rows = read_results(run_dir / RESULTS_FILE)
    assert foreign_rows(config, rows) == []
    assert foreign_rows(small_config(limit=3), rows) == []  # grown in place: its own rows
    other = small_config(limit=1, max_action_len=3)
    assert foreign_rows(other, rows)[0].startswith(f"{rows[0].split}/{rows[0].episode_id}: ")
    renamed = small_config(limit=1, system="another system")
    assert "system 'test system', not 'another system'" in foreign_rows(renamed, rows)[0]

    (run_dir / "config.yaml").unlink()  # the run's config lost, another given
    with pytest.raises(ConfigError, match=r"were made by another configuration than its"):
        run(other, run_dir)
    # Its own config back, the run and its scores are whole again; a foreign row is not.
    (run_dir / "config.yaml").write_text(config.to_yaml())
    assert run(config, run_dir).ran_now == 0
    lines = (run_dir / RESULTS_FILE).read_text().splitlines()
    first = json.loads(lines[1])  # the first row, after the header
    first["extra"]["settings_digest"] = other.settings_digest()
    lines[1] = json.dumps(first)
    (run_dir / RESULTS_FILE).write_text("\n".join(lines) + "\n")
    scored = cli("score", str(run_dir), "--out", str(tmp_path / "scores"))
    assert scored.code == 2 and "another configuration" in scored.err, scored
    allowed = cli("score", str(run_dir), "--out", str(tmp_path / "s"), "--allow-incomplete")
    assert allowed.code == 2 and "another configuration" in allowed.err, allowed  # never
    copied = tmp_path / "elsewhere" / "results.jsonl"  # out of its run directory
    copied.parent.mkdir()
    own = json.loads(lines[1]) | {"episode_id": "1913__99_1"}  # a row of the run's own
    own["extra"] = own["extra"] | {"settings_digest": config.settings_digest()}
    copied.write_text("\n".join([*lines, json.dumps(own)]) + "\n")
    alone = cli("score", str(copied), "--out", str(tmp_path / "c"))
    assert alone.code == 2 and "has rows made by different settings" in alone.err, alone


def test_one_systems_runs_of_different_configurations_are_not_pooled(
    tmp_path: Path, small_config: MakeConfig, cli: Any
) -> None:
    # An audit scored an official run on val_unseen and another configuration's run on
    # val_seen under one label: one table row, its columns made by different settings.
    from skyvln_eval.metrics import score_results

    unseen, seen, other = tmp_path / "unseen", tmp_path / "seen", tmp_path / "other"
    assert run(small_config(limit=1), unseen).complete
    assert run(small_config(limit=1, splits=("val_seen",)), seen).complete
    assert run(small_config(limit=1, splits=("val_seen",), max_action_len=3), other).complete
    # The same configuration on two splits, in two runs: one system, scored together.
    same = cli("score", str(unseen), str(seen), "--out", str(tmp_path / "s1"))
    assert same.code == 0, same
    mixed = cli("score", str(unseen), str(other), "--out", str(tmp_path / "s2"))
    assert mixed.code == 2, mixed
    assert "has rows made by different run configurations" in mixed.err, mixed
    rows = read_results(unseen / RESULTS_FILE) + read_results(other / RESULTS_FILE)
    with pytest.raises(ResultRecordError, match="give the runs different system labels"):
        score_results(rows)


def test_an_official_run_records_no_flight_settings_and_keeps_rows_made_with_them(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit: official-mode runs recorded "dynamics: {controller: nmpc, obstacles:
    # crossing}" in config.yaml and every run MCAP, though nothing flew, and a changed
    # flight setting (unused) refused the resume.
    import dataclasses

    from skyvln_eval.harness.run import foreign_rows
    from skyvln_eval.harness.runner import log_path

    config = small_config(limit=1)
    assert config.mode == "official"
    run_dir = tmp_path / "run"
    assert run(config, run_dir).complete
    assert "dynamics" not in yaml.safe_load((run_dir / "config.yaml").read_text())
    [row] = read_results(run_dir / RESULTS_FILE)
    meta = read_log(log_path(run_dir, row.split, row.episode_id)).metadata[t.RUN_METADATA]
    assert "dynamics" not in yaml.safe_load(meta["config"]) and "seed" in meta["config"]
    changed = small_config(limit=1, dynamics={"cruise_speed_m_s": 10.0})
    assert run(changed, run_dir).ran_now == 0
    # Rows recorded while the settings digest covered the unused flight settings.
    legacy = config.legacy_settings_digest()
    assert legacy is not None and legacy != config.settings_digest()
    older = dataclasses.replace(row, extra=row.extra | {"settings_digest": legacy})
    assert foreign_rows(config, [older]) == []
    assert small_config(limit=1, mode="dynamics").legacy_settings_digest() is None


def test_a_resume_with_other_code_is_recorded_and_warns_that_the_run_mixes_versions(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit resumed a run after changing the code: no warning, and versions.json kept
    # only the new commit, so nothing could tell the two versions' rows apart.
    run_dir = tmp_path / "run"
    first = run(small_config(limit=1), run_dir)
    assert not any("WARNING" in note for note in first.notes)
    versions = json.loads((run_dir / "versions.json").read_text())
    assert [launch["rows_before"] for launch in versions["launches"]] == [0]
    versions["launches"][0]["git"] = {"commit": "0123456789abcdef", "dirty": False}
    (run_dir / "versions.json").write_text(json.dumps(versions))
    again = run(small_config(limit=1), run_dir)  # nothing to run: no row of other code
    assert not any("WARNING" in note for note in again.notes)
    assert len(json.loads((run_dir / "versions.json").read_text())["launches"]) == 1
    grown = run(small_config(limit=2), run_dir)  # a row made now, by this code
    warning = next(note for note in grown.notes if note.startswith("WARNING"))
    assert "rows were made by 2 versions" in warning
    assert "commit 0123456789 from row 0" in warning
    launches = json.loads((run_dir / "versions.json").read_text())["launches"]
    assert [launch["rows_before"] for launch in launches] == [0, 1]
    later = run(small_config(limit=2), run_dir)  # said again while the rows are mixed
    assert any("rows were made by 2 versions" in note for note in later.notes)
    assert json.loads((run_dir / "run.json").read_text())["notes"] == later.notes


def test_a_launch_stopped_on_the_way_leaves_a_run_json_that_says_so(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit grew a finished run (24 episodes) to 45 and stopped it: run.json still said
    # "expected 24, missing []", the last finished launch's account.
    from skyvln_eval.harness.run import Progress

    class StopAfterOne(Progress):
        def episode_done(self, result: Any, success: bool | None) -> None:
            raise KeyboardInterrupt

    run_dir = tmp_path / "run"
    assert run(small_config(limit=1), run_dir).complete
    assert json.loads((run_dir / "run.json").read_text())["finished"] is True
    with pytest.raises(KeyboardInterrupt):
        run(small_config(limit=3), run_dir, progress=StopAfterOne())
    stopped = json.loads((run_dir / "run.json").read_text())
    assert stopped["finished"] is False and stopped["expected"] == 3
    # Where the launch got: one episode done before it, one in it, one left.
    assert stopped["already_done"] == 1 and stopped["ran_now"] == 1
    assert len(stopped["missing"]) == 1


def test_a_recorded_episode_whose_run_log_is_gone_runs_again_on_resume(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit deleted a run MCAP: the resume said "already done" and the log stayed lost.
    config = small_config(limit=2)
    run_dir = tmp_path / "run"
    assert run(config, run_dir).complete
    before = read_results(run_dir / RESULTS_FILE)
    lost = run_dir / "logs" / before[0].split / f"{before[0].episode_id}.mcap"
    lost.unlink()
    again = run(config, run_dir)
    assert (again.ran_now, again.already_done) == (1, 1)
    assert any(
        "1 recorded episode(s) run again: a file of theirs was missing or damaged" in n
        for n in again.notes
    )
    assert lost.is_file() and not check_log(lost).issues
    after = {r.episode_id: r for r in read_results(run_dir / RESULTS_FILE)}
    assert [comparable(after[r.episode_id]) for r in before] == [comparable(r) for r in before]
    # A log cut short is as lost as a deleted one (only its presence was checked).
    lost.write_bytes(lost.read_bytes()[:-20])
    again = run(config, run_dir)
    assert (again.ran_now, again.already_done) == (1, 1)
    assert any("missing or damaged" in n and "truncated" in n for n in again.notes), again.notes
    assert not check_log(lost).issues


def test_an_episode_file_cut_short_is_damaged(tmp_path: Path) -> None:
    """What a resume checks of a recorded episode's files: present and with both ends."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from skyvln_eval.harness.run import file_damage

    control = tmp_path / "episode.parquet"
    pq.write_table(pa.table({"t": [0.0, 0.1]}), control)
    assert file_damage(control) is None
    control.write_bytes(control.read_bytes()[:-6])
    assert file_damage(control) == "damaged: truncated or not a parquet file"
    assert file_damage(tmp_path / "none.parquet") == "missing"
    log = tmp_path / "episode.mcap"
    log.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 40)
    damage = file_damage(log)
    assert damage is not None and damage.startswith("damaged: truncated or unfinished MCAP")


def test_score_reads_the_runs_below_a_folder_and_drops_a_layout_of_other_systems(
    tmp_path: Path, small_config: MakeConfig, cli: Any
) -> None:
    # An audit: `score` refused a reproduction's output ("a directory without
    # results.jsonl") where validate found its runs, and scores written into a folder
    # holding another reproduction's tables.json made tables that left their systems out.
    from skyvln_eval.reports.table_layout import (
        LAYOUT_FILE,
        ReproducedTables,
        TableLayout,
        write_layout,
    )

    config = small_config(limit=1, agent={"name": "random"})
    assert run(config, tmp_path / "rep" / "runs" / "test-system" / "val_unseen").complete
    out = tmp_path / "rep" / "scores"
    out.mkdir()
    others = ReproducedTables({"table1": TableLayout(("Random",), ())}, 10, 0, ())
    write_layout(out, others)
    scored = cli("score", str(tmp_path / "rep"), "--out", str(out), "--resamples", "0")
    assert scored.code == 0, scored
    assert f"removed {out / LAYOUT_FILE}" in scored.out and not (out / LAYOUT_FILE).exists()
    # A layout that places the system scored (the same runs scored again) is kept.
    own = ReproducedTables({"table1": TableLayout((config.system,), ())}, 10, 0, ())
    write_layout(out, own)
    again = cli("score", str(tmp_path / "rep" / "runs"), "--out", str(out), "--resamples", "0")
    assert again.code == 0, again
    assert (out / LAYOUT_FILE).is_file()


def test_a_relative_data_path_names_the_folder_it_named_when_the_run_was_launched(
    tmp_path: Path, small_config: MakeConfig, sample_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # An audit grew a run with `data: ds` from another directory, where `ds` was a copy
    # with other dialogs: accepted without a word, the new rows flown on other data.
    from skyvln_eval.reports.run_coverage import run_data_dir

    name = sample_dir.name  # relative, from the folder that holds the sample
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / name / "annotations").mkdir(parents=True)  # another folder of that name
    run_dir = tmp_path / "run"
    monkeypatch.chdir(sample_dir.parent)
    assert run(small_config(data=name, limit=1), run_dir).complete
    report = json.loads((run_dir / "run.json").read_text())
    assert report["relative_data_dir"] == str(sample_dir.resolve())
    monkeypatch.chdir(elsewhere)
    with pytest.raises(ConfigError, match=rf"from here '{name}' is .*elsewhere/{name}: run the"):
        run(small_config(data=name, limit=2), run_dir)
    # Scored from elsewhere, the run's rows are checked against the folder it ran on.
    assert run_data_dir(small_config(data=name, limit=1), run_dir) == sample_dir.resolve()
    monkeypatch.chdir(sample_dir.parent)
    assert run(small_config(data=name, limit=2), run_dir).ran_now == 1
    # A damaged record is refused, naming it (an audit: it lifted the check, and a resume
    # from elsewhere then wrote the other folder into run.json).
    (run_dir / "run.json").write_text('{"system": "aud')
    monkeypatch.chdir(elsewhere)
    with pytest.raises(ConfigError, match=r"run\.json: cannot be read .* restore the file"):
        run(small_config(data=name, limit=3), run_dir)
    with pytest.raises(ConfigError, match=r"run\.json: cannot be read"):
        run_data_dir(small_config(data=name, limit=1), run_dir)


def test_segments_cut_short_by_their_time_limit_are_counted(
    tmp_path: Path, small_config: MakeConfig
) -> None:
    # An audit: with max_segment_time_s 1 no segment arrived, and the run said "ok, 0
    # crashed, 0 with failed solver steps" (segments_reached was written, read nowhere).
    from skyvln_eval.harness.commands import describe_report

    dynamics = {"controller": "pid", "controller_settings": {}, "max_segment_time_s": 1.0}
    config = small_config(
        mode="dynamics", limit=1, agent={"name": "ground_truth"}, dynamics=dynamics
    )
    report = run(config, tmp_path / "run")
    (row,) = read_results(tmp_path / "run" / RESULTS_FILE)
    assert row.segments_cut_short == len(row.extra["segments_reached"]) > 0
    assert report.flights["with segments cut short"] == 1
    saved = json.loads((tmp_path / "run" / "run.json").read_text())
    assert saved["flights"]["with segments cut short"] == 1
    assert any(
        "1 with a segment cut short at max_segment_time_s" in line
        for line in describe_report(report)
    )
    # The scores carry the count (the control table's column), an episode not flown none.
    scores = score_results([row], MetricConventions())
    assert scores["segments_cut_short"].tolist() == [row.segments_cut_short]
    official = small_config(limit=1, agent={"name": "ground_truth"})
    run(official, tmp_path / "official")
    (unflown,) = read_results(tmp_path / "official" / RESULTS_FILE)
    assert unflown.segments_cut_short is None
