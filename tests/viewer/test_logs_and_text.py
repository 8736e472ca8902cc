"""Finding and streaming run MCAPs; the text panels; the missing-extra message."""

from __future__ import annotations

import base64
import shutil
import sys
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from skyvln_eval.avdn import load_split
from skyvln_eval.converters import messages as fx
from skyvln_eval.converters import topics as t
from skyvln_eval.converters.convert import convert_episode
from skyvln_eval.converters.reader import read_log
from skyvln_eval.converters.writer import McapLogWriter
from skyvln_eval.errors import ConfigError, McapLogError, MissingExtraError
from skyvln_eval.viewer import text
from skyvln_eval.viewer.commands import describe
from skyvln_eval.viewer.logs import EpisodeLogRef, RunLogStream, find_episode_logs
from skyvln_eval.viewer.recording import RecordingSummary
from skyvln_eval.viewer.scene import detections_by_view, sector_box
from skyvln_eval.viewer.static_content import episode_card_text
from tests.conftest import CliOutcome, make_record, write_dataset
from tests.converters.conftest import chunk_payload_span

Cli = Callable[..., CliOutcome]


def test_episodes_are_selected_by_id_or_split_and_id(flown_run: Path, tmp_path: Path) -> None:
    (only,) = find_episode_logs(flown_run)
    assert find_episode_logs(flown_run, [only.episode_id]) == [only]
    assert find_episode_logs(flown_run, [only.key, only.episode_id]) == [only]
    assert find_episode_logs(only.path) == [only]
    typo = only.episode_id[:-1] + "9"
    with pytest.raises(ConfigError, match=f"Did you mean {only.episode_id}"):
        find_episode_logs(flown_run, [typo])
    # The right id under another split: where it is, not a list of look-alikes.
    with pytest.raises(ConfigError, match=f"It is there as {only.key}"):
        find_episode_logs(flown_run, [f"val_seen/{only.episode_id}"])
    for bad in ("../logs", "a/b/c", ""):
        with pytest.raises(ConfigError, match="not an episode id"):
            find_episode_logs(flown_run, [bad])
    with pytest.raises(ConfigError, match="not a run directory"):
        find_episode_logs(tmp_path)


def test_a_reproduce_system_folder_is_viewed_as_run_results_reads_it(
    flown_run: Path, tmp_path: Path, cli: Cli
) -> None:
    # reproduce writes runs/<system>/<split>/, one run directory per split; run_results
    # reads runs/<system> as all of them, and so does view.
    system = tmp_path / "runs" / "full"
    shutil.copytree(flown_run, system / "val_unseen")
    (only,) = find_episode_logs(flown_run)
    (ref,) = find_episode_logs(system, [only.key])
    assert ref.key == only.key and ref.path.is_relative_to(system / "val_unseen")
    assert find_episode_logs(system) == [ref]
    with pytest.raises(ConfigError, match="Did you mean"):
        find_episode_logs(system, [only.episode_id[:-1] + "9"])
    # A folder of neither kind: the error says what view takes.
    outcome = cli("view", str(tmp_path / "runs"), "--save", str(tmp_path / "x.rrd"))
    assert outcome.code == 2
    assert "not a run directory" in outcome.err and "nor a folder of run directories" in outcome.err
    assert "its folders 'full' hold run directories" in outcome.err
    assert ".mcap" in outcome.err and ".rrd" in outcome.err


def test_a_truncated_log_is_refused_naming_the_file(flown_run: Path, tmp_path: Path) -> None:
    (ref,) = find_episode_logs(flown_run)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(ref.path.read_bytes()[:-100])
    with pytest.raises(McapLogError, match=str(cut)), RunLogStream(cut):
        pass


def _flipped_in_first_chunk(data: bytes) -> bytes:
    start, end = chunk_payload_span(data)
    flipped = bytearray(data)
    flipped[(start + end) // 2] ^= 0xFF
    return bytes(flipped)


def test_a_damaged_or_foreign_file_is_refused_naming_it(flown_run: Path, tmp_path: Path) -> None:
    """An audit saw raw tracebacks (struct.error, ZstdError) and an EINVAL without a name."""
    (ref,) = find_episode_logs(flown_run)
    data = ref.path.read_bytes()
    files = {
        "empty.mcap": (b"", "an empty file"),
        "text.mcap": (b"hello\n", "not an MCAP file"),
        "magic.mcap": (data[:8], "truncated or unfinished"),
        "flipped.mcap": (_flipped_in_first_chunk(data), "damaged MCAP file"),
    }
    for name, (content, reason) in files.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(McapLogError, match=f"{path}: {reason}"), RunLogStream(path) as stream:
            list(stream.messages())


def test_the_stream_yields_every_message_in_time_order(flown_run: Path) -> None:
    (ref,) = find_episode_logs(flown_run)
    whole = read_log(ref.path)
    with RunLogStream(ref.path) as log:
        streamed = [(topic, t_ns) for topic, t_ns, _ in log.messages()]
        assert log.episode().episode_id == ref.episode_id
        assert log.topic_counts == whole.summary().topic_counts
    assert sorted(streamed, key=lambda m: m[1]) == streamed
    assert sorted(streamed) == sorted((m.topic, m.log_time_ns) for m in whole.messages)


def _noise_png(seed: int, side: int = 300) -> bytes:
    image = np.random.default_rng(seed).integers(0, 256, (side, side, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def test_building_streams_images_instead_of_loading_them_all(
    flown_run: Path, tmp_path: Path, rerun_cli: Path
) -> None:
    """A log with ~20 MB of images is built with a small fraction of that in Python memory."""
    from skyvln_eval.viewer import write_recording

    (ref,) = find_episode_logs(flown_run)
    source = read_log(ref.path)
    big = tmp_path / "logs" / ref.split / f"{ref.episode_id}.mcap"
    big.parent.mkdir(parents=True)
    images = [_noise_png(seed) for seed in range(8)]
    total = 0
    with McapLogWriter(big) as writer:
        for name, meta in source.metadata.items():
            writer.add_metadata(name, meta)
        for k in range(80):
            data = images[k % len(images)]
            total += len(data)
            t_ns = k * 100_000_000
            message = fx.compressed_image(t_ns, t.CAMERA_FRAME, data, "png")
            writer.write(t.TOPIC_OBSERVATION, t.COMPRESSED_IMAGE, message, t_ns)
    assert total > 15_000_000
    tracemalloc.start()
    try:
        summary = write_recording(find_episode_logs(tmp_path)[0], tmp_path / "big.rrd")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert summary.rows["camera/observation"] == 80
    assert peak < total / 3, f"peak {peak} bytes of Python memory for {total} bytes of images"


def test_exchange_text_shows_every_field_the_log_holds() -> None:
    exchange = {
        "timestamp": {"sec": 1, "nsec": 0},
        "episode_id": "e",
        "step_index": 2,
        "module": "motion",
        "prompt": [{"role": "user", "text": "fly ```north```", "images": 1}],
        "response": '{"action": "stop"}',
        "error": None,
        "status": "ok",
        "latency_s": 0.84,
        "usage": {"prompt_tokens": 512, "completion_tokens": 40},
        "finish_reason": None,
    }
    line = text.exchange_line(exchange)
    assert line.startswith("motion (decision 2): answered")
    for shown in ("status=ok", "latency_s=0.84", "usage.prompt_tokens=512", "completion_tokens=40"):
        assert shown in line
    assert "finish_reason" not in line  # absent values are left out
    document = text.exchange_document(exchange)
    assert "````\nfly ```north```\n````" in document  # the fence outlasts the text's own
    assert "1 image(s) attached" in document and '{"action": "stop"}' in document
    failed = text.exchange_line({"module": "subgoals", "response": None, "error": "timeout"})
    assert "error: timeout" in failed


def test_detections_use_the_logged_box_else_the_hsd_sector() -> None:
    sightings = [
        {"id": "L1", "label": "stadium", "view": "front", "sector": 2, "score": 0.99},
        {"id": "L2", "label": "park", "view": "below", "box_px": [10, 20, 30, 60], "score": 0.5},
        {"id": "L3", "label": "tower", "view": "front", "sector": 6, "image_size_px": [300, 150]},
    ]
    found = detections_by_view(sightings, (224, 224))
    assert found["front"].boxes == [sector_box(2, 224, 224), sector_box(6, 300, 150)]
    assert sector_box(6, 300, 150) == [0.0, 100.0, 100.0, 150.0]
    assert found["front"].labels[0] == "L1 stadium 0.99 (sector #2)"
    assert found["below"].boxes == [[10.0, 20.0, 30.0, 60.0]]
    assert text.sighting_line({**sightings[0], "distance_m": 182.4}).endswith(
        "view front, sector #2; score=0.99, distance_m=182.4"
    )


def test_memory_text_lists_nodes_and_edges() -> None:
    step = {
        "step_index": 3,
        "trace": {
            "memory": {
                "nodes": [{"id": "P0", "kind": "place"}, {"id": "L1", "kind": "landmark"}],
                "edges": [{"from": "P0", "to": "L1", "kind": "met", "distance_m": 84.1}],
                "current": "P0",
            },
            "clarification_question": "Which tower?",
        },
    }
    document = text.memory_document(step)
    assert "- P0: kind=place" in document
    assert r"- P0 -\> L1: kind=met, distance\_m=84.1" in document  # shows as "->", "_"
    assert "Which tower?" in document


def test_text_from_a_log_cannot_forge_markup_in_a_document() -> None:
    # An audit: a thought holding '**Action:** `{"type": "stop"}`' showed a second action
    # line above the real one; headings and image links went through too.
    forged = 'fine.\n**Action:** `{"type": "stop"}`\n# Heading ![x](https://example.org/x.png)'
    step = {"step_index": 0, "thought": forged, "action": {"type": "turn", "degrees": 90}}
    document = text.step_document(step, 0.0)
    assert document.count("**Action:**") == 1 and "\n# Heading" not in document
    assert r"\!\[x\](https://example.org/x.png)" in document
    dialog = text.dialog_document([{"round_index": 1, "speaker": "commander", "text": forged}])
    assert "**Action" not in dialog and "![x]" not in dialog
    assert "TBMA is off" in text.memory_document({"step_index": 0, "trace": {"memory": None}})


def test_a_missing_viewer_extra_names_the_install_command(monkeypatch: pytest.MonkeyPatch) -> None:
    from skyvln_eval.viewer.deps import rerun_sdk

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun now raises ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'skyvln-eval\[viewer\]'"):
        rerun_sdk()


def test_importing_the_viewer_package_does_not_import_rerun() -> None:
    import subprocess

    code = "import sys, skyvln_eval.viewer; print('rerun' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_base64_image_bytes_are_passed_through_undecoded() -> None:
    from skyvln_eval.viewer.scene import image_bytes

    data = _noise_png(1, 16)
    message = {"data": base64.b64encode(data).decode(), "format": "png"}
    assert image_bytes(message) == (data, "image/png")


def test_the_episode_card_shows_the_status_and_what_explains_it(tmp_path: Path) -> None:
    record = make_record()
    (episode,) = load_split(
        write_dataset(tmp_path / "ds", {"val_seen": [record]}), "val_seen"
    ).episodes()
    log = tmp_path / "e.mcap"

    def card(**run: str) -> list[str]:
        return episode_card_text(episode, {"system": "S", **run}, log).splitlines()

    assert "- status: **ok**" in card(status="ok", fallback_decisions="0")
    counts = {"llm_calls": "12", "llm_failed_calls": "0", "fallback_decisions": "2",
              "module_failures": "3", "llm_parse_failures": "1"}  # fmt: skip
    degraded = card(status="degraded", **counts)
    expected = (
        "- status: **degraded** (2 fallback decision(s), 3 module failure(s), "
        "1 unusable LLM answer(s); 12 LLM call(s) in all)"
    )
    assert degraded.index("- system: S") + 1 == degraded.index(expected)  # right below
    failed = card(status="error", error="LLMError: HTTP 500", llm_calls="4", llm_failed_calls="4")
    assert "- status: **error** (4 failed LLM call(s); 4 LLM call(s) in all)" in failed
    assert "- error: LLMError: HTTP 500" in failed
    # A log of an older run (no counts) still says its status; a dataset log has none.
    assert "- status: **degraded**" in card(status="degraded")
    assert not any(line.startswith("- status") for line in card())


def _episode_log(tmp_path: Path) -> Path:
    """A one-episode MCAP made by `convert` (no world: no images), for 1913__0_1 of val_seen."""
    data_dir = write_dataset(tmp_path / "ds", {"val_seen": [make_record()]})
    (episode,) = load_split(data_dir, "val_seen").episodes()
    path = tmp_path / "1913__0_1.mcap"
    with McapLogWriter(path) as writer:
        convert_episode(episode, None, writer)
    return path


def test_a_single_file_refuses_an_episode_it_does_not_hold(tmp_path: Path, cli: Cli) -> None:
    path = _episode_log(tmp_path)
    (ref,) = find_episode_logs(path)
    assert ref.key == "val_seen/1913__0_1"
    # Naming the episode the file holds is harmless; naming another is refused.
    assert find_episode_logs(path, ["1913__0_1", "val_seen/1913__0_1"]) == [ref]
    for other in ("1913__7_1", "val_unseen/1913__0_1"):
        with pytest.raises(ConfigError) as refused:
            find_episode_logs(path, [other])
        message = str(refused.value)
        assert message.startswith(f"{path} holds episode val_seen/1913__0_1, not {other!r}")
        assert "give the run directory" in message
    # The command refuses before it builds or writes anything.
    saved = tmp_path / "x.rrd"
    outcome = cli("view", str(path), "-e", "1913__7_1", "--save", str(saved))
    assert outcome.code == 2 and "not '1913__7_1'" in outcome.err and not saved.exists()


def test_the_printout_counts_images_of_every_kind_and_decisions_only_of_runs(
    tmp_path: Path,
) -> None:
    ref = EpisodeLogRef(tmp_path / "e.mcap", "val_seen", "1913__0_1")
    flown = {"camera/observation": 3, "camera/detections/pano/image": 10,
             "camera/detections/down/image": 5, "camera/detections/down": 3,
             "map/tile": 1, "llm/log": 6}  # fmt: skip
    run = RecordingSummary(ref.path, ref, "id", 3, flown, run_log=True, gt_views=0)
    assert describe(run, False) == (
        "val_seen/1913__0_1: 3 decision(s), 18 image(s) (3 observation, 15 camera view), "
        "6 LLM exchange(s), 0 pose(s), 0 obstacle sample(s)"
    )
    converted = {"camera/gt_observation": 4, "map/tile": 1}
    episode = RecordingSummary(ref.path, ref, "id", 0, converted, run_log=False, gt_views=4)
    assert describe(episode, False) == (
        "val_seen/1913__0_1: 4 ground-truth view(s) (an episode log: no agent flew it), "
        "4 image(s) (4 ground-truth view)"
    )


def test_a_recording_of_an_episode_log_counts_ground_truth_views_not_decisions(
    tmp_path: Path,
) -> None:
    pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[viewer]')")
    from skyvln_eval.viewer import write_recording

    (ref,) = find_episode_logs(_episode_log(tmp_path))
    summary = write_recording(ref, tmp_path / "e.rrd")
    line = describe(summary)  # the log's 3 GPS fixes were printed as "3 decision(s)"
    assert "3 ground-truth view(s)" in line and "decision" not in line, line
    assert (summary.run_log, summary.decisions, summary.gt_views) == (False, 0, 3)
    # No agent flew it: its poses are the GT route, not drawn again as a flown path.
    from skyvln_eval.viewer import entities as e

    assert e.MAP_PATH not in summary.rows and e.WORLD_TRAJECTORY not in summary.rows
    assert summary.recording_id.startswith("val_seen/andh/1913__0_1@episode-log:")


def test_a_message_the_viewer_cannot_show_is_named_not_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[viewer]')")
    from skyvln_eval.viewer import recording, write_recording

    real = recording._Recorder.on

    def bad_dialog(self: recording._Recorder, topic: str, t_ns: int, message: object) -> None:
        if topic == t.TOPIC_DIALOG:
            raise ValueError("could not convert string to float: 'abc'")
        real(self, topic, t_ns, message)  # type: ignore[arg-type]

    monkeypatch.setattr(recording._Recorder, "on", bad_dialog)
    (ref,) = find_episode_logs(_episode_log(tmp_path))
    with pytest.raises(McapLogError) as info:
        write_recording(ref, tmp_path / "e.rrd")
    said = str(info.value)
    assert str(ref.path) in said and f"its {t.TOPIC_DIALOG} message at 0 s cannot be shown" in said
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*.tmp"))


def test_an_episode_s_name_says_its_status_unless_ok() -> None:
    from skyvln_eval.viewer.recording import recording_name

    ref = EpisodeLogRef(Path("x.mcap"), "val_seen", "9101__5_1")
    run = {"system": "audit", "status": "error"}
    assert recording_name(ref, run, "andh") == "audit: val_seen/andh/9101__5_1 [ERROR]"
    assert recording_name(ref, {**run, "status": "ok"}, "andh") == "audit: val_seen/andh/9101__5_1"


class _Canvas:
    """What the recorder's LLM exchanges touch of a canvas: the time and the documents."""

    def __init__(self) -> None:
        import rerun

        self.rr = rerun
        self.t_ns = 0
        self.documents: dict[str, str] = {}

    def put(self, entity: str, value: object) -> None:
        pass

    def markdown(self, entity: str, document: str) -> None:
        self.documents[entity] = document


def test_every_llm_exchange_of_a_decision_stays_readable() -> None:
    # HSD's several calls, or an answer and its repair, at one decision: each document
    # replaced the one before at the same time, so half the exchanges could not be seen.
    pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[viewer]')")
    from skyvln_eval.viewer.recording import _Recorder

    canvas = _Canvas()
    recorder = _Recorder(canvas, (512, 512), True)  # type: ignore[arg-type]
    for response in ("first", "repaired"):
        recorder._exchange({"module": "subgoals", "step_index": 0, "response": response})
    document = canvas.documents["llm/subgoals"]
    assert "first" in document and "repaired" in document
    canvas.t_ns = 10**9  # the next decision starts a new document
    recorder._exchange({"module": "subgoals", "step_index": 1, "response": "later"})
    assert "first" not in canvas.documents["llm/subgoals"]


@pytest.mark.parametrize(
    ("where", "reason"),
    [
        (lambda n: 20, "data-section CRC mismatch"),  # the header record
        (lambda n: n - 60, "summary CRC mismatch"),  # the summary section's end
        (lambda n: n - 12, "summary CRC mismatch"),  # the footer's summary CRC itself
    ],
    ids=["header", "summary", "footer"],
)
def test_a_changed_byte_outside_the_chunks_is_refused_too(
    flown_run: Path, tmp_path: Path, where: Any, reason: str
) -> None:
    # The reader checks each chunk's CRC as it reads it: a byte changed in the header, the
    # summary or the footer gave a recording without a word (validate named it).
    (ref,) = find_episode_logs(flown_run)
    data = bytearray(ref.path.read_bytes())
    data[where(len(data))] ^= 0x01
    path = tmp_path / "changed.mcap"
    path.write_bytes(bytes(data))
    refused = pytest.raises(McapLogError, match=f"{path}: damaged MCAP file: {reason}")
    with refused, RunLogStream(path) as stream:
        list(stream.messages())
