"""A tiny randomly initialised GroundingDINO, built from a config, for tests without downloads.

A small Swin backbone, a one-layer BERT text encoder and a word-level vocabulary written
here: the folder it is saved to loads through ``from_pretrained`` exactly as downloaded
weights do, so the detector's normal path (``model=<folder>``) is what the tests run.
The model knows nothing: its boxes and scores are random but deterministic (seeded
weights, eval mode), which is all the tests of plumbing need.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

VISION_EXTRA = "needs torch and transformers: pip install 'skyvln-eval[vision]'"

#: Every word the tests' landmark phrases use; other words become [UNK].
VOCABULARY = (
    "[PAD]",
    "[UNK]",
    "[CLS]",
    "[SEP]",
    "[MASK]",
    ".",
    "a",
    "the",
    "red",
    "black",
    "roof",
    "restaurant",
    "church",
    "gas",
    "station",
    "building",
    "park",
)


def require_vision() -> Any:
    """``transformers``, or skip the test saying how to install it."""
    # tests/conftest.py sets it before huggingface_hub is imported; this says it is relied on.
    assert os.environ.get("HF_HUB_OFFLINE") == "1", "the tests must not reach the hub"
    pytest.importorskip("torch", reason=VISION_EXTRA)
    return pytest.importorskip("transformers", reason=VISION_EXTRA)


def build_tiny_grounding_dino(folder: Path, seed: int = 0) -> Path:
    """Save a tiny random GroundingDINO (processor and weights) into ``folder``."""
    transformers = require_vision()
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "vocab.txt").write_text("\n".join(VOCABULARY) + "\n", encoding="utf-8")
    tokenizer = transformers.BertTokenizerFast.from_pretrained(str(folder))
    # 128 px input: the backbone's last level (plus the extra one) stays above 1 x 1, which
    # the model's group norms need.
    image_processor = transformers.GroundingDinoImageProcessor(
        size={"shortest_edge": 128, "longest_edge": 128}
    )
    backbone = transformers.SwinConfig(
        image_size=128,
        patch_size=4,
        embed_dim=8,
        depths=[1, 1, 1, 1],
        num_heads=[1, 1, 1, 1],
        window_size=4,
        out_features=["stage2", "stage3", "stage4"],
    )
    text = transformers.BertConfig(
        vocab_size=len(VOCABULARY),
        hidden_size=16,
        num_hidden_layers=1,
        num_attention_heads=2,
        intermediate_size=32,
        max_position_embeddings=64,
    )
    config = transformers.GroundingDinoConfig(
        backbone_config=backbone,
        text_config=text,
        d_model=32,  # its group norms have 32 groups
        encoder_layers=1,
        decoder_layers=2,  # the box heads of later decoder layers are tied to the first's
        encoder_ffn_dim=32,
        decoder_ffn_dim=32,
        encoder_attention_heads=2,
        decoder_attention_heads=2,
        encoder_n_points=2,
        decoder_n_points=2,
        num_queries=20,
        max_text_len=32,
    )
    torch.manual_seed(seed)
    model = transformers.GroundingDinoForObjectDetection(config).eval()
    processor = transformers.GroundingDinoProcessor(image_processor, tokenizer)
    processor.save_pretrained(str(folder))
    model.save_pretrained(str(folder))
    return folder


def count_model_loads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names GroundingDINO weights are loaded from from now on (transformers'
    ``from_pretrained`` of zero-shot detection models, wrapped for the test's duration)."""
    auto = require_vision().AutoModelForZeroShotObjectDetection
    original = auto.from_pretrained
    loads: list[str] = []

    def counting(name: str, *args: object, **kwargs: object) -> object:
        loads.append(name)
        return original(name, *args, **kwargs)

    monkeypatch.setattr(auto, "from_pretrained", counting)
    return loads
