"""Recordings checked with Rerun's own tools against the run MCAP they were built from."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

from skyvln_eval.converters import topics as t
from skyvln_eval.converters.reader import episode_from_log, read_log
from skyvln_eval.frames import latlng_to_enu
from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer.logs import find_episode_logs
from tests.viewer.tools import rerun_tool

_CHUNK = re.compile(r"^Chunk\(\S+\) with (\d+) rows \(.*?\) - (\S+) - ")


def rows_by_entity(printed: str) -> Counter[str]:
    """Rows per entity path, summed over the chunks `rerun rrd print` lists."""
    rows: Counter[str] = Counter()
    for line in printed.splitlines():
        if match := _CHUNK.match(line):
            rows[match.group(2)] += int(match.group(1))
    return rows


@pytest.fixture(scope="module")
def recording(flown_run: Path, rerun_cli: Path, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    from skyvln_eval.viewer import write_recording

    (ref,) = find_episode_logs(flown_run)
    summary = write_recording(ref, tmp_path_factory.mktemp("rrd") / "episode.rrd")
    return ref, summary


def test_rerun_verifies_the_saved_recording(recording, rerun_cli: Path) -> None:  # type: ignore[no-untyped-def]
    _, summary = recording
    result = rerun_tool(rerun_cli, "rrd", "verify", str(summary.path))
    assert result.returncode == 0, result.stderr
    assert "1 file verified without error" in result.stdout + result.stderr
    # Written under a temporary name and renamed: nothing else is left beside it.
    assert [p.name for p in summary.path.parent.iterdir()] == [summary.path.name]


def test_entities_and_counts_match_the_run_mcap(recording, rerun_cli: Path) -> None:  # type: ignore[no-untyped-def]
    ref, summary = recording
    printed = rerun_tool(rerun_cli, "rrd", "print", str(summary.path))
    assert printed.returncode == 0, printed.stderr
    rows = rows_by_entity(printed.stdout)
    # The MCAP side is counted with the converters' verifying reader, not the viewer's.
    log = read_log(ref.path)
    poses = [m for m in log.topic(t.TOPIC_TF) if m.decode()["child_frame_id"] == t.DRONE_FRAME]
    counts = {topic: len(log.topic(topic)) for topic in t.TOPICS}
    assert counts[t.TOPIC_CONTROL_STEP] > 50 and counts[t.TOPIC_OBSTACLES] > 5  # it flew
    # One drone pose per time: a decision's view does not repeat the control step's.
    pose_times = [m.log_time_ns for m in poses]
    assert len(set(pose_times)) == len(pose_times)

    assert rows[f"/{e.WORLD_DRONE}"] == len(poses)
    assert rows[f"/{e.MAP_DRONE}"] == len(poses)
    # The airframe tilts as flown (an audit: the box hung level on the heading frame).
    body = [m for m in log.topic(t.TOPIC_TF) if m.decode()["child_frame_id"] == t.BODY_FRAME]
    assert len(body) == counts[t.TOPIC_CONTROL_STEP]
    assert summary.rows[e.WORLD_DRONE_BODY] == len(body) <= rows[f"/{e.WORLD_DRONE_BODY}"]
    assert rows[f"/{e.CAMERA_OBSERVATION}"] == counts[t.TOPIC_OBSERVATION] > 0
    views = {path for path in rows if path.startswith(f"/{e.MAP_VIEWS}/")}
    assert len(views) == counts[t.TOPIC_RUN_VIEWS] > 0
    assert all(rows[path] == 1 for path in views)
    assert rows[f"/{e.MAP_FINAL_VIEW}"] == 1
    assert rows[f"/{e.LLM_LOG}"] == counts[t.TOPIC_LLM_EXCHANGE] > 0
    by_module = sum(
        n for path, n in rows.items() if path.startswith(f"/{e.LLM}/") and path != f"/{e.LLM_LOG}"
    )
    assert by_module == counts[t.TOPIC_LLM_EXCHANGE]
    assert rows[f"/{e.WORLD_OBSTACLES}"] == counts[t.TOPIC_OBSTACLES]
    # The controller's predicted horizon, once per control step that has one.
    predicted = [m.decode()["predicted_positions_m"] for m in log.topic(t.TOPIC_CONTROL_STEP)]
    with_horizon = [p for p in predicted if p is not None]
    assert len(with_horizon) > 50 and all(len(p) == 21 for p in with_horizon)
    assert rows[f"/{e.WORLD_HORIZON}"] >= len(with_horizon)
    # Every image the agent's camera gave it, under the view's name, with that view's boxes.
    steps = [m.decode() for m in log.topic(t.TOPIC_AGENT_STEP)]
    assert counts[t.TOPIC_CAMERA_VIEWS] == sum(len(s["trace"]["views"]) for s in steps) > 0
    # Each image's frame is in /tf when it was taken, for the 3-D panel to place.
    frames = {
        (m.log_time_ns, m.decode()["child_frame_id"])
        for m in log.topic(t.TOPIC_TF)
        if m.decode()["child_frame_id"].startswith(t.CAMERA_VIEW_FRAME_PREFIX)
    }
    image_frames = {
        (m.log_time_ns, m.decode()["frame_id"]) for m in log.topic(t.TOPIC_CAMERA_VIEWS)
    }
    assert frames == image_frames
    names = {v["name"] for s in steps for v in s["trace"]["views"]}
    images = {
        path: n
        for path, n in rows.items()
        if path.startswith(f"/{e.CAMERA_DETECTIONS}/") and path.endswith("/image")
    }
    assert set(images) == {f"/{e.camera_view(name)}/image" for name in names}
    assert sum(images.values()) == counts[t.TOPIC_CAMERA_VIEWS]
    # Detections are drawn where the detector boxed them, inside their image.
    sightings = [s for m in log.topic(t.TOPIC_AGENT_STEP) for s in m.decode()["trace"]["sightings"]]
    assert sightings
    for s in sightings:
        x0, y0, x1, y1 = s["box_px"]
        width, height = s["image_size_px"]
        assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height, s
    for entity in (e.AGENT_STEP, e.AGENT_HSD, e.AGENT_MEMORY, e.AGENT_LOG):
        assert rows[f"/{entity}"] == counts[t.TOPIC_AGENT_STEP] > 0
    for series in ("x_m/state", "x_m/reference", "yaw_rad/reference", "solve_time_ms"):
        assert rows[f"/{e.CONTROL}/{series}"] == counts[t.TOPIC_CONTROL_STEP]
    for static in (e.MAP_TILE, e.MAP_GT_ROUTE, e.MAP_GT_VIEWS, e.MAP_GOAL, e.WORLD_GT_ROUTE):
        assert rows[f"/{static}"] >= 1, static
    assert rows[f"/{e.DIALOG}"] == counts[t.TOPIC_DIALOG] > 0
    # The recording is the episode's, on both timelines.
    assert f'"{summary.recording_id}"' in printed.stdout
    detail = rerun_tool(
        rerun_cli, "rrd", "print", "-vv", "--entity", f"/{e.CAMERA_OBSERVATION}", str(summary.path)
    )
    assert f"index_name: {e.DECISION_TIMELINE}" in detail.stdout
    assert f"index_name: {e.SIM_TIMELINE}" in detail.stdout
    # What the builder says it logged is what Rerun reads back.
    for path, n in summary.rows.items():
        if not path.startswith(f"{e.CONTROL}/"):
            assert rows[f"/{path}"] >= n, path


def test_map_pixels_are_the_official_ones(flown_run: Path) -> None:
    (ref,) = find_episode_logs(flown_run)
    episode = episode_from_log(read_log(ref.path))
    corners = episode.gt_path_corners[0]
    frame = e.MapFrame(episode.georef)
    official = episode.georef.gps_to_pixel_float(corners)
    assert frame.pixels(latlng_to_enu(corners, episode.georef)) == pytest.approx(official, abs=1e-6)
    width, height = frame.size_px
    assert official[:, 0].min() > 0 and official[:, 0].max() < width
    assert official[:, 1].min() > 0 and official[:, 1].max() < height


def test_the_application_id_is_one_rerun_takes_as_it_is(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # Rerun rewrote ids with '/' and '@', warning on stderr once per recording (20 lines
    # from reproduce) and appending a hash, so the viewer showed another id than ours.
    import rerun as rr

    from skyvln_eval.viewer.recording import application_id

    app = application_id("val_seen/andh/9101__10_1@e9ecfa839f98")
    assert app == "skyvln-eval:val_seen-andh-9101__10_1-e9ecfa839f98"
    rec = rr.RecordingStream(app, recording_id="check")
    rec.save(tmp_path / "check.rrd")
    rec.flush()
    rec.disconnect()
    assert "migrat" not in capfd.readouterr().err


class _Stream:
    """What a recording stream is told of time, call by call."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, ...]] = []

    def set_time(self, timeline: str, **value: object) -> None:
        self.calls.append(("set", timeline))

    def disable_timeline(self, timeline: str) -> None:
        self.calls.append(("off", timeline))


def test_the_flight_between_decisions_is_not_put_on_the_decision_timeline() -> None:
    # An audit: control-step poses took the last decision's index, so at decision k the
    # drone stood where it was just before decision k+1, away from decision k's view.
    from skyvln_eval.viewer.canvas import Canvas

    stream = _Stream()
    canvas = Canvas(None, stream, None, [0, 10_000])  # type: ignore[arg-type]
    for t_ns, continuous in ((0, True), (5_000, True), (5_000, False), (10_000, True)):
        stream.calls.clear()
        canvas.at(t_ns, continuous=continuous)
        decision = stream.calls[0]
        assert decision[1] == e.DECISION_TIMELINE and ("set", e.SIM_TIMELINE) in stream.calls
        on_decisions = t_ns in (0, 10_000) or not continuous
        assert decision[0] == ("set" if on_decisions else "off"), (t_ns, continuous)


def test_two_runs_of_one_configuration_are_two_recordings(flown_run: Path, tmp_path: Path) -> None:
    # A run copied beside itself (or one configuration run twice): its episode's two logs
    # became one recording, every row twice, the two flights drawn over each other.
    import shutil

    from skyvln_eval.viewer.commands import build_recordings

    for name in ("a", "b"):
        shutil.copytree(flown_run, tmp_path / "runs" / name)
    refs = find_episode_logs(tmp_path / "runs")
    summaries = build_recordings(refs, tmp_path / "rrd")
    ids = [s.recording_id for s in summaries]
    assert len(refs) == 2 and len(set(ids)) == 2
    assert len({i.rsplit(":", 1)[0] for i in ids}) == 1  # the same episode and configuration


def test_decisions_that_share_a_time_are_said_to_be_merged(flown_run: Path, tmp_path: Path) -> None:
    # An audit: a log with two decisions at one time (a segment of no step, before every
    # segment took one) shifted every later decision on the timeline, without a word.
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    from skyvln_eval.viewer import write_recording
    from skyvln_eval.viewer.commands import describe
    from skyvln_eval.viewer.logs import EpisodeLogRef

    (ref,) = find_episode_logs(flown_run)
    with ref.path.open("rb") as source:
        times = sorted(m.log_time for _, c, m in make_reader(source).iter_messages()
                       if c.topic == t.TOPIC_AGENT_STEP)  # fmt: skip
    first, second = times[:2]
    retimed = tmp_path / ref.path.name
    with ref.path.open("rb") as source, retimed.open("wb") as out:
        reader = make_reader(source)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start()
        schemas = {i: writer.register_schema(s.name, s.encoding, s.data)
                   for i, s in summary.schemas.items()}  # fmt: skip
        channels = {
            i: writer.register_channel(
                c.topic, c.message_encoding, schemas[c.schema_id], dict(c.metadata)
            )
            for i, c in summary.channels.items()
        }
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, dict(record.metadata))
        for _, channel, message in reader.iter_messages(log_time_order=True):
            at = first if message.log_time == second else message.log_time
            writer.add_message(channels[channel.id], at, message.data, at)
        writer.finish()
    merged = write_recording(EpisodeLogRef(retimed, ref.split, ref.episode_id), tmp_path / "m.rrd")
    assert merged.merged_decisions == 1
    assert "1 decision(s) at a time another has: merged on the decision timeline" in describe(
        merged
    )
    plain = write_recording(ref, tmp_path / "p.rrd")
    assert plain.merged_decisions == 0


def test_at_a_flown_time_the_control_step_comes_before_the_path_so_far(flown_run: Path) -> None:
    # An audit: the path was written first, so the viewer's flown path at decision k ended
    # one control step short of the drone.
    from mcap.reader import make_reader

    (ref,) = find_episode_logs(flown_run)
    with ref.path.open("rb") as source:
        order = [(m.log_time, c.topic) for _, c, m in make_reader(source).iter_messages()]
    controlled = {at for at, topic in order if topic == t.TOPIC_CONTROL_STEP}
    paths = [k for k, (at, topic) in enumerate(order) if topic == t.TOPIC_RUN_PATH]
    flown = [k for k in paths if order[k][0] in controlled]
    assert flown  # the decisions after the first were flown to
    for k in flown:
        at = order[k][0]
        assert any(order[j] == (at, t.TOPIC_CONTROL_STEP) for j in range(k)), at
