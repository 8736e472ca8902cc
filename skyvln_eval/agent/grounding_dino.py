"""GroundingDINO through ``transformers``: open-vocabulary boxes on RGB from landmark phrases.

Needs the ``vision`` extra (``pip install 'skyvln-eval[vision]'``) and the weights on disk:
the toolkit never downloads at run time (``local_files_only``), so fetch them once (e.g.
``huggingface-cli download IDEA-Research/grounding-dino-tiny``) or pass a local folder as
``model``. Both are checked when the detector is built, with an error saying which is
missing.

Weights are loaded once per process and device (:func:`load_model`): the harness builds
an agent, and so a detector, for every episode, and reloading hundreds of megabytes each
time would cost more than the episode. ``threads`` sets torch's intra-op threads for the
process (1 by default): the harness already runs one episode per core, and torch's
threads on top of that oversubscribe the cores; a tiny model was seen 50 times slower
with 2 threads than with 1 on a busy 2-core machine.

The post-processing is transformers' ``post_process_grounded_object_detection`` with the
``threshold`` / ``text_threshold`` arguments and the ``text_labels`` result key, both
present since transformers 4.49 (the ``vision`` extra's lower bound). A text label is the
prompt's tokens whose score passed ``text_threshold``; the detection's label is the
phrase those tokens belong to (:func:`match_phrase`).
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyvln_eval.agent.detectors import Detection, Detector, clip_box, colour_name
from skyvln_eval.errors import ConfigError, MissingExtraError
from skyvln_eval.sensing import CameraImages
from skyvln_eval.vocabulary.landmarks import CATEGORY_LABELS

DEFAULT_MODEL = "IDEA-Research/grounding-dino-tiny"
#: What is looked for when no phrase is asked for: the vocabulary's landmark kinds and the
#: things every aerial view holds.
OPEN_VOCABULARY: tuple[str, ...] = (
    *CATEGORY_LABELS.values(),
    "building",
    "parking lot",
    "road",
    "field",
)
_WORD = re.compile(r"[a-z0-9]+")
_SPECIAL_TOKEN = re.compile(r"\[[A-Z]+\]")  # [CLS], [SEP], [PAD] in decoded text labels


@dataclass(frozen=True)
class LoadedModel:
    """A processor and model pair, ready for inference on ``device``; ``weights_sha256``
    the digest of its weight files (two checkpoints in one folder are told apart)."""

    processor: Any
    model: Any
    torch: Any
    device: str
    transformers_version: str
    weights_sha256: str = ""


_LOADED: dict[tuple[str, str], LoadedModel] = {}
_LOAD_LOCK = threading.Lock()


def _model_key(model: str) -> str:
    """A local folder by its absolute path (``./m`` and ``/abs/m`` are one model), else the
    hub name as written."""
    path = Path(model).expanduser()
    return str(path.resolve()) if path.is_dir() else model


def load_model(model: str, device: str = "cpu") -> LoadedModel:
    """The processor and weights of ``model`` on ``device``, loaded once per process.

    Raises :class:`MissingExtraError` when transformers or torch are not installed, and
    :class:`ConfigError` when the weights are not on this machine or are incomplete.
    """
    key = (_model_key(model), device)
    with _LOAD_LOCK:  # thread executors build detectors concurrently: load only once
        loaded = _LOADED.get(key)
        if loaded is None:
            loaded = _load(key[0], device)
            _LOADED[key] = loaded
        return loaded


def _load(model: str, device: str) -> LoadedModel:
    try:
        import torch
        import transformers
        from transformers import AutoModelForZeroShotObjectDetection, AutoProcessor
    except ImportError as error:
        raise MissingExtraError(
            "the GroundingDINO detector", "vision", f"cannot import {error.name}"
        ) from error
    check_weights_present(model)
    try:
        processor = AutoProcessor.from_pretrained(model, local_files_only=True)
        weights, info = AutoModelForZeroShotObjectDetection.from_pretrained(
            model, local_files_only=True, output_loading_info=True
        )
    except OSError as error:
        raise ConfigError(f"{_not_found(model)} ({type(error).__name__})") from None
    _refuse_incomplete(model, info)
    return LoadedModel(
        processor,
        weights.to(device).eval(),
        torch,
        device,
        transformers.__version__,
        weights_digest(model),
    )


def _model_file(model: str, name: str) -> Path | None:
    """The file ``name`` of ``model``: in its folder, or in the Hugging Face cache; None
    when it is not on this machine."""
    path = Path(model).expanduser()
    if path.is_dir():
        return path / name if (path / name).is_file() else None
    from huggingface_hub import try_to_load_from_cache

    found = try_to_load_from_cache(model, name)
    return Path(found) if isinstance(found, str) else None


def _weight_files(model: str) -> list[Path]:
    """The files holding ``model``'s weights: in its folder, or in the Hugging Face cache."""
    path = Path(model).expanduser()
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix in (".safetensors", ".bin"))
    return [f for name in _WEIGHT_NAMES if (f := _model_file(model, name)) is not None]


def weights_digest(model: str) -> str:
    """SHA-256 of ``model``'s weight files, in name order (read once per process, about a
    second for the tiny model's 700 MB): what a run's settings record of its detector."""
    digest = hashlib.sha256()
    for path in _weight_files(model):
        digest.update(path.name.encode())
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def _looks_local(model: str) -> bool:
    """Whether ``model`` is written as a folder (``/``, ``./``, ``../``, ``~``), not a hub id."""
    return model.startswith(("/", "./", "../", "~")) or Path(model).expanduser().is_dir()


def _not_found(model: str) -> str:
    """Why the weights of ``model`` cannot be used, and what to do: never "check your
    internet connection" (nothing is downloaded at run time), nor "pip install"."""
    if _looks_local(model):
        return f"detector model folder {model} does not exist or holds no GroundingDINO weights"
    cache = os.environ.get("HF_HUB_CACHE") or os.environ.get("HF_HOME") or "~/.cache/huggingface"
    return (
        f"the weights of detector model {model!r} are not in the Hugging Face cache ({cache}); "
        "the toolkit never downloads at run time: run `huggingface-cli download "
        f"{model}` on a machine with a connection (and copy the cache here), or set "
        "agent.detector.model to a local folder"
    )


def check_weights_present(model: str) -> None:
    """Refuse ``model`` unless its config and weights are on this machine (a local folder,
    or the Hugging Face cache), without loading them: what a run checks before flying."""
    if _looks_local(model) and not Path(model).expanduser().is_dir():
        raise ConfigError(_not_found(model))
    try:
        present = _model_file(model, "config.json") is not None and bool(_weight_files(model))
    except ImportError as error:  # transformers brings huggingface_hub; without it, no load
        raise MissingExtraError(
            "the GroundingDINO detector", "vision", f"cannot import {error.name}"
        ) from error
    if not present:
        raise ConfigError(_not_found(model))


#: Where a checkpoint's weights are, by the names transformers saves them under.
_WEIGHT_NAMES = ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin")


def _refuse_incomplete(model: str, info: dict[str, Any]) -> None:
    """A checkpoint that lacks tensors, or holds some of another shape, loads with those
    layers at random (transformers says so on stderr alone): its boxes would be scored as
    a trained detector's. Refused, naming a few."""
    missing = list(info.get("missing_keys") or [])
    mismatched = [
        str(m[0]) if isinstance(m, tuple) else str(m) for m in info.get("mismatched_keys") or []
    ]
    if not missing and not mismatched:
        return
    parts = []
    if missing:
        parts.append(f"{len(missing)} tensor(s) missing (e.g. {', '.join(missing[:3])})")
    if mismatched:
        parts.append(f"{len(mismatched)} of another shape (e.g. {', '.join(mismatched[:3])})")
    raise ConfigError(
        f"detector model {model!r} is incomplete: {'; '.join(parts)}; those layers would run "
        "with random weights. Fetch the checkpoint again"
    )


def clean_phrases(phrases: Sequence[str]) -> dict[str, str]:
    """Prompt text of each distinct phrase -> the phrase as given, in order.

    GroundingDINO reads lower-case phrases separated by full stops, so a full stop inside
    a phrase would split it: it becomes a space.
    """
    out: dict[str, str] = {}
    for phrase in phrases:
        text = " ".join(phrase.lower().replace(".", " ").split())
        if text and text not in out:
            out[text] = phrase
    return out


def match_phrase(text_label: str, prompts: Sequence[str]) -> str | None:
    """The prompt phrase a decoded text label belongs to, or ``None`` if it shares no word.

    A text label is the run of prompt tokens that passed the text threshold, so it can
    span two phrases or hold part of one: the phrase with most words in common wins, then
    the one it covers best, then the earlier one.
    """
    words = set(_WORD.findall(_SPECIAL_TOKEN.sub(" ", text_label).lower()))
    best: tuple[int, float, int] | None = None
    chosen = None
    for index, prompt in enumerate(prompts):
        phrase_words = set(_WORD.findall(prompt))
        common = len(words & phrase_words)
        if not common:
            continue
        rank = (common, common / len(phrase_words), -index)
        if best is None or rank > best:
            best, chosen = rank, prompt
    return chosen


class GroundingDinoDetector(Detector):
    """Text-prompted boxes on RGB; the label is the phrase matched, the caption the colour
    measured in the box."""

    name = "grounding_dino"
    requires = frozenset({"rgb"})

    def __init__(
        self,
        model: str = DEFAULT_MODEL,
        box_threshold: float = 0.35,
        text_threshold: float = 0.25,
        device: str = "cpu",
        threads: int | None = 1,
    ) -> None:
        self._loaded = load_model(model, device)
        if threads is not None:
            self._loaded.torch.set_num_threads(threads)  # process-wide, as the note says
        self.model_name = model
        self.box_threshold = box_threshold
        self.text_threshold = text_threshold
        self.device = device
        self.threads = threads

    def settings(self) -> dict[str, Any]:
        return {
            **super().settings(),
            "model": self.model_name,
            "box_threshold": self.box_threshold,
            "text_threshold": self.text_threshold,
            "device": self.device,
            "threads": self.threads,
            "transformers": self._loaded.transformers_version,
            "weights_sha256": self._loaded.weights_sha256,
        }

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        # An agent without landmark phrases of its own (the NavGPT-style baseline) gets
        # what an open-vocabulary detector would find: the landmark kinds of the toolkit's
        # vocabulary, not nothing (which would leave it blind on real imagery).
        prompts = clean_phrases(phrases or OPEN_VOCABULARY)
        loaded = self._loaded
        text = ". ".join(prompts) + "."
        max_tokens = int(loaded.model.config.max_text_len)
        inputs = loaded.processor(
            images=images.rgb,
            text=text,
            truncation=True,
            max_length=max_tokens,
            return_tensors="pt",
        ).to(loaded.device)
        with loaded.torch.no_grad():
            outputs = loaded.model(**inputs)
        width, height = images.size_px
        result = loaded.processor.post_process_grounded_object_detection(
            outputs,
            inputs["input_ids"],
            threshold=self.box_threshold,
            text_threshold=self.text_threshold,
            target_sizes=[(height, width)],
        )[0]
        out = []
        for box, score, text_label in zip(
            result["boxes"].tolist(),
            result["scores"].tolist(),
            result["text_labels"],
            strict=True,
        ):
            prompt = match_phrase(str(text_label), list(prompts))
            clipped = clip_box(box, width, height)
            if prompt is None or clipped is None:
                continue  # tokens of no phrase (only separators), or a box off the image
            phrase = prompts[prompt]
            x0, y0, x1, y1 = clipped
            # The label is what the model matched; the caption only what the pixels show
            # (the phrase's own words there claimed a colour no one measured, an audit).
            caption = f"{colour_name(images.rgb[y0:y1, x0:x1])} in its box"
            out.append(Detection(phrase, clipped, float(np.clip(score, 0.0, 1.0)), caption))
        return out
