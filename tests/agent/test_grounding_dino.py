"""GroundingDINO on rendered RGB: a tiny random model built in the test, loaded through the
detector's normal path (a local folder), never downloaded; weights loaded once per process."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest

from skyvln_eval.agent import create_detector
from skyvln_eval.agent.config import DetectorConfig
from skyvln_eval.agent.detectors import clip_box, colour_name
from skyvln_eval.agent.grounding_dino import (
    OPEN_VOCABULARY,
    GroundingDinoDetector,
    clean_phrases,
    match_phrase,
)
from skyvln_eval.sensing import CameraImages, SensorConfig
from skyvln_eval.sim.sensors import SimulatedSensors
from tests.toy_worlds import town_world
from tests.vision_models import build_tiny_grounding_dino, count_model_loads, require_vision

PHRASES = ["red restaurant", "Church", "gas station"]


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    require_vision()
    return build_tiny_grounding_dino(tmp_path_factory.mktemp("models") / "grounding-dino-tiny")


def rgb_view(heading_deg: float = 0.0) -> CameraImages:
    """What an RGB-only drone above the town's crossing sees (no depth, no semantic camera)."""
    sensors = SimulatedSensors(
        town_world(), 300.0, 300.0, 60.0, SensorConfig(depth=False, semantic=False)
    )
    return sensors.capture(heading_deg, 60.0)


@pytest.mark.filterwarnings("error::FutureWarning")  # the deprecated `labels` key warns
def test_detect_on_rendered_pixels_gives_well_formed_detections(tiny_model: Path) -> None:
    detector = create_detector(
        "grounding_dino", model=str(tiny_model), box_threshold=0.05, text_threshold=0.3
    )
    assert detector.requires == {"rgb"}
    view = rgb_view()
    assert view.semantic is None and view.depth_m is None  # pixels are all it gets
    width, height = view.size_px
    found = detector.detect(view, PHRASES)
    assert found, "a low threshold keeps some of the random model's boxes"
    for detection in found:
        x0, y0, x1, y1 = detection.box_px
        assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
        assert 0.0 <= detection.score <= 1.0
        assert detection.label in PHRASES  # the phrase as given ("Church", not "church")
        # The caption is measured, not the phrase again (it claimed the phrase's colour).
        assert detection.caption.endswith(" in its box") and detection.mask is None
        x0, y0, x1, y1 = detection.box_px
        assert detection.caption == f"{colour_name(view.rgb[y0:y1, x0:x1])} in its box"
    # Seeded weights in eval mode: the same pixels give the same detections.
    again = detector.detect(view, PHRASES)
    assert [(d.label, d.box_px, d.score) for d in again] == [
        (d.label, d.box_px, d.score) for d in found
    ]
    # The pixels matter: another view gives other boxes or scores.
    behind = detector.detect(rgb_view(180.0), PHRASES)
    assert [(d.box_px, d.score) for d in behind] != [(d.box_px, d.score) for d in found]


def test_thresholds_and_phrases_decide_what_is_kept(tiny_model: Path) -> None:
    view = rgb_view()
    strict = GroundingDinoDetector(str(tiny_model), box_threshold=1.0)
    assert strict.detect(view, PHRASES) == []  # no score exceeds 1
    loose = GroundingDinoDetector(str(tiny_model), box_threshold=0.0, text_threshold=0.3)
    # Nothing asked for (the NavGPT-style baseline): the open vocabulary, not nothing.
    found = [(d.label, d.box_px, d.score) for d in loose.detect(view, [])]
    assert found and found == [
        (d.label, d.box_px, d.score) for d in loose.detect(view, OPEN_VOCABULARY)
    ]
    assert len(loose.detect(view, PHRASES)) >= len(
        GroundingDinoDetector(str(tiny_model), box_threshold=0.5).detect(view, PHRASES)
    )
    settings = loose.settings()
    assert settings["name"] == "grounding_dino" and settings["model"] == str(tiny_model)
    assert settings["requires"] == ["rgb"] and settings["transformers"]


def test_weights_are_loaded_once_per_process_for_many_detectors(
    tiny_model: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fresh = tmp_path / "fresh-model"  # a model this process has not loaded yet
    shutil.copytree(tiny_model, fresh)
    loads = count_model_loads(monkeypatch)
    # As the harness does: one agent, so one detector, per episode.
    detectors = [
        DetectorConfig(name="grounding_dino", model=str(fresh)).build(seed) for seed in range(6)
    ]
    monkeypatch.chdir(tmp_path)
    detectors.append(create_detector("grounding_dino", model="fresh-model"))  # same folder
    assert loads == [str(fresh.resolve())]
    assert len({id(d._loaded.model) for d in detectors}) == 1  # type: ignore[attr-defined]


def test_text_labels_become_the_phrase_they_belong_to() -> None:
    prompts = list(clean_phrases(["Red restaurant", "church.", "gas station", "church"]))
    assert prompts == ["red restaurant", "church", "gas station"]  # lower case, no stops
    assert match_phrase("church", prompts) == "church"
    assert match_phrase("red restaurant [SEP]", prompts) == "red restaurant"
    assert match_phrase("red", prompts) == "red restaurant"  # part of one phrase
    # Tokens of two phrases: the one with more words in common, then the better covered.
    assert match_phrase("church gas station", prompts) == "gas station"
    assert match_phrase("church restaurant", prompts) == "church"
    assert match_phrase("[CLS] . [SEP]", prompts) is None  # separators only
    assert match_phrase("", prompts) is None


def test_boxes_are_clipped_to_the_image_in_whole_pixels() -> None:
    assert clip_box((-5.2, 3.7, 40.1, 250.0), 224, 224) == (0, 3, 41, 224)
    assert clip_box((10.0, 10.0, 10.4, 20.0), 224, 224) == (10, 10, 11, 20)
    assert clip_box((230.0, 10.0, 260.0, 20.0), 224, 224) is None  # right of the image
    assert clip_box((5.0, 5.0, math.nan, 9.0), 224, 224) is None


def test_a_checkpoint_missing_tensors_is_refused_not_run_with_random_layers(
    tiny_model: Path, tmp_path: Path
) -> None:
    # An audit: without its box heads the model loaded with those layers at random
    # (transformers said so on stderr alone), detected with scores near 1 and the run was ok.
    from safetensors.torch import load_file, save_file

    from skyvln_eval.errors import ConfigError

    partial = tmp_path / "partial"
    shutil.copytree(tiny_model, partial)
    state = load_file(str(tiny_model / "model.safetensors"))
    kept = {k: v for k, v in state.items() if "bbox_embed" not in k}
    assert len(kept) < len(state)
    save_file(kept, str(partial / "model.safetensors"), metadata={"format": "pt"})
    with pytest.raises(ConfigError, match=r"is incomplete: \d+ tensor\(s\) missing \(e\.g\. "):
        create_detector("grounding_dino", model=str(partial))


def test_the_settings_name_the_weights_by_their_digest(tiny_model: Path) -> None:
    import hashlib

    detector = create_detector("grounding_dino", model=str(tiny_model))
    files = sorted(p for p in tiny_model.iterdir() if p.suffix in (".safetensors", ".bin"))
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.name.encode() + path.read_bytes())
    assert files and detector.settings()["weights_sha256"] == digest.hexdigest()


def test_a_local_folder_is_checked_for_a_config_and_weights_of_either_format(
    tmp_path: Path,
) -> None:
    from skyvln_eval.agent.grounding_dino import check_weights_present
    from skyvln_eval.errors import ConfigError

    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "config.json").write_text("{}")
    with pytest.raises(ConfigError, match="holds no GroundingDINO weights"):
        check_weights_present(str(folder))
    (folder / "pytorch_model.bin").write_bytes(b"weights")  # the older format is found too
    check_weights_present(str(folder))
