"""`skyvln-eval view`: saving, serving on the loopback only, analytics off."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from skyvln_eval.viewer.commands import recording_file_names
from skyvln_eval.viewer.logs import find_episode_logs
from skyvln_eval.viewer.privacy import rerun_environment
from tests.conftest import REPO
from tests.processes import alive, as_a_terminal_job, children
from tests.viewer.tools import rerun_tool, run_skyvln_eval, skyvln_eval_command


def test_rerun_processes_run_with_analytics_off(rerun_cli: Path) -> None:
    env = rerun_environment()  # what the toolkit gives every rerun process it starts
    result = rerun_tool(rerun_cli, "analytics", "config")
    assert result.returncode == 0, result.stderr
    config = json.loads(result.stdout)
    assert config["analytics_enabled"] is False
    assert config["config_file_path"].startswith(env["XDG_CONFIG_HOME"])
    assert "Welcome to Rerun" not in result.stderr  # no first-run notice: a config exists


def test_the_served_viewer_listens_on_the_loopback_only_with_a_policy(
    flown_run: Path, rerun_cli: Path, tmp_path: Path
) -> None:
    import psutil

    from skyvln_eval.viewer import write_recording
    from skyvln_eval.viewer.serve import serve_recordings

    (ref,) = find_episode_logs(flown_run)
    summary = write_recording(ref, tmp_path / "episode.rrd")
    with serve_recordings([summary.path], port=0) as viewer:
        with urllib.request.urlopen(viewer.url, timeout=30) as response:
            page = response.read().decode()
            policy = response.headers["Content-Security-Policy"]
            # Each header once: the proxy's own Server and Date, not the viewer's as well.
            assert len(response.headers.get_all("Server")) == 1
            assert len(response.headers.get_all("Date")) == 1
        grpc_port = int(viewer.grpc_url.rsplit(":", 1)[1].split("/")[0])
        assert "re_viewer.js" in page
        assert f"connect-src 'self' http://127.0.0.1:{grpc_port}" in policy
        assert "default-src 'self'" in policy
        listening = [
            c.laddr
            for c in psutil.Process(viewer.process.pid).net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN
        ]
        assert {a.port for a in listening} >= {grpc_port}
        assert {a.ip for a in listening} == {"127.0.0.1"}
        assert viewer.proxy.server_address[0] == "127.0.0.1"
        process = viewer.process
    assert process.poll() is not None  # closing stopped the rerun process it started


def test_a_taken_port_is_a_clear_error_and_leaves_no_process(
    flown_run: Path, rerun_cli: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import socket
    import tempfile

    import psutil

    from skyvln_eval.viewer import write_recording
    from skyvln_eval.viewer.serve import ViewerServeError, serve_recordings

    (ref,) = find_episode_logs(flown_run)
    summary = write_recording(ref, tmp_path / "episode.rrd")
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ViewerServeError, match=f"cannot listen on 127.0.0.1:{port}"):
            serve_recordings([summary.path], port=port)
    rerun_children = [
        c
        for c in psutil.Process().children(recursive=True)
        if c.name() == rerun_cli.name and c.status() != psutil.STATUS_ZOMBIE
    ]
    assert not rerun_children
    assert list(scratch.iterdir()) == []  # nor its log


def test_view_saves_one_episode_and_names_unknown_ones(flown_run: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[viewer]')")
    (ref,) = find_episode_logs(flown_run)
    out = tmp_path / "one.rrd"
    result = run_skyvln_eval(
        "view", str(flown_run), "--episode", ref.episode_id, "--save", str(out)
    )
    assert result.returncode == 0, result.stderr
    assert out.is_file() and out.stat().st_size > 10_000
    assert f"{ref.key}: " in result.stdout and "decision(s)" in result.stdout
    assert f"open with: skyvln-eval view {out}  (or `rerun {out}`;" in result.stdout
    assert "FILE.rrd" not in result.stdout  # the file saved, not a placeholder
    bad = run_skyvln_eval("view", str(flown_run), "--episode", "nope", "--save", str(out))
    assert bad.returncode == 2
    assert "no run MCAP for episode 'nope'" in bad.stderr


def test_the_open_hint_names_what_was_saved() -> None:
    from skyvln_eval.viewer.commands import open_hint

    one = open_hint([Path("my run/ep.rrd")], Path("my run/ep.rrd"))
    assert one.startswith(
        "open with: skyvln-eval view 'my run/ep.rrd'  (or `rerun 'my run/ep.rrd'`;"
    )
    several = open_hint([Path("out/a.rrd"), Path("out/b.rrd")], Path("out"))
    assert several.startswith(
        "open one with: skyvln-eval view out/a.rrd  (or all: `rerun out/*.rrd`;"
    )


def _start_view(flown_run: Path, scratch: Path) -> tuple[subprocess.Popen[str], str]:
    """``skyvln-eval view`` on the run's episode, and the URL it printed once serving; its
    temporary files go to ``scratch``."""
    (ref,) = find_episode_logs(flown_run)
    scratch.mkdir()
    command = skyvln_eval_command("view", str(flown_run), "--episode", ref.key, "--port", "0")
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env={**os.environ, "TMPDIR": str(scratch)},
        preexec_fn=as_a_terminal_job,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.stdout is not None:
        line = process.stdout.readline()
        if "http://127.0.0.1:" in line:
            return process, line[line.index("http://") :].strip()
    process.kill()
    process.wait(timeout=10)
    raise AssertionError("the command printed no viewer URL")


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_view_serves_until_stopped_and_cleans_up(
    flown_run: Path, rerun_cli: Path, tmp_path: Path, stop: signal.Signals
) -> None:
    scratch = tmp_path / "tmp"
    process, url = _start_view(flown_run, scratch)
    servers = children(process.pid)
    try:
        with urllib.request.urlopen(url, timeout=30) as response:
            assert response.status == 200
        assert list(scratch.iterdir())  # the recording being served and the server's log
        process.send_signal(stop)
        out, _ = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
    assert process.returncode == 0
    assert "stopped" in out
    assert list(scratch.iterdir()) == []
    assert servers and not any(alive(pid) for pid in servers)


def test_several_episodes_saved_as_one_file_keep_one_recording_each(
    flown_run: Path, rerun_cli: Path, tmp_path: Path
) -> None:
    (ref,) = find_episode_logs(flown_run)
    for split in ("val_seen", "test_unseen"):  # the same log under two splits: two episodes
        copy = tmp_path / "run" / "logs" / split / ref.path.name
        copy.parent.mkdir(parents=True)
        copy.write_bytes(ref.path.read_bytes())
    out = tmp_path / "both.rrd"
    result = run_skyvln_eval("view", str(tmp_path / "run"), "--save", str(out))
    assert result.returncode == 0, result.stderr
    assert "saved 2 recording(s)" in result.stdout
    printed = rerun_tool(rerun_cli, "rrd", "print", str(out)).stdout
    for split in ("val_seen", "test_unseen"):
        assert f'"{split}/andh/{ref.episode_id}@' in printed
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    refused = run_skyvln_eval("view", str(out), "--save", str(tmp_path / "again.rrd"))
    assert refused.returncode == 2 and "already a recording" in refused.stderr
    # An .rrd that is not one was served as an empty viewer, with no error (an audit).
    fake = tmp_path / "fake.rrd"
    fake.write_text("# not a recording\n")
    refused = run_skyvln_eval("view", str(fake), "--port", "1")
    assert refused.returncode == 2 and f"{fake}: not a Rerun recording" in refused.stderr


def test_one_damaged_log_of_a_run_is_skipped_and_said_the_rest_saved(
    flown_run: Path, tmp_path: Path
) -> None:
    # An audit: one cut-off log stopped the whole view; the episodes after it were lost.
    (ref,) = find_episode_logs(flown_run)
    data = ref.path.read_bytes()
    for split, body in (("val_seen", data[: len(data) // 2]), ("test_unseen", data)):
        copy = tmp_path / "run" / "logs" / split / ref.path.name
        copy.parent.mkdir(parents=True)
        copy.write_bytes(body)
    out = tmp_path / "out"
    result = run_skyvln_eval("view", str(tmp_path / "run"), "--save", str(out))
    assert result.returncode == 1, result.stderr
    assert "skipped: " in result.stderr and "truncated or unfinished MCAP file" in result.stderr
    assert "1 of 2 episode log(s) skipped as damaged" in result.stderr
    assert [p.name for p in out.iterdir()] == [f"test_unseen__{ref.episode_id}.rrd"]


def test_runs_of_one_folder_that_flew_the_same_episode_keep_a_file_each(
    flown_run: Path, tmp_path: Path
) -> None:
    # An audit: two runs of a folder (e.g. runs/ after two configs) holding one episode
    # were built into one temporary name: the second replaced the first, and "saved 4"
    # meant 3.
    for name in ("first", "second"):
        shutil.copytree(flown_run, tmp_path / "runs" / name)
    refs = find_episode_logs(tmp_path / "runs")
    assert len(refs) == 2 and refs[0].key == refs[1].key
    out = tmp_path / "out"
    result = run_skyvln_eval("view", str(tmp_path / "runs"), "--save", str(out))
    assert result.returncode == 0, result.stderr
    episode = f"{refs[0].split}__{refs[0].episode_id}.rrd"
    assert sorted(p.name for p in out.iterdir()) == [f"first__{episode}", f"second__{episode}"]
    twice = [f"first__{episode[:-4]}__{k}.rrd" for k in (1, 2)]  # one run named twice
    assert recording_file_names([refs[0], refs[0]]) == twice


@pytest.mark.skipif(sys.platform != "linux", reason="the parent-death signal is Linux's")
def test_a_killed_view_command_leaves_no_rerun_server(
    flown_run: Path, rerun_cli: Path, tmp_path: Path
) -> None:
    process, _ = _start_view(flown_run, tmp_path / "tmp")  # what SIGKILL leaves stays there
    servers = children(process.pid)
    try:
        assert servers, "the view command started no rerun server"
        process.kill()  # SIGKILL: no clean-up of the toolkit's runs
        process.wait(timeout=10)
        deadline = time.monotonic() + 30
        while any(alive(pid) for pid in servers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(alive(pid) for pid in servers), "the rerun server outlived the viewer"
    finally:
        for pid in servers:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
