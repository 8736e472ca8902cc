"""GroundingDINO through ``transformers``: open-vocabulary detection from landmark phrases.

Needs the ``vision`` extra (``pip install 'skyvln-eval[vision]'``) and the model weights
on disk: the toolkit never downloads at run time (``local_files_only``), so fetch them
once (e.g. ``huggingface-cli download IDEA-Research/grounding-dino-tiny``) or pass a local
folder as ``model``. Both are checked when the detector is built, with an error that says
which is missing.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from skyvln_eval.agent.detectors import Detection, Detector
from skyvln_eval.errors import MissingExtraError
from skyvln_eval.sensing import CameraImages

DEFAULT_MODEL = "IDEA-Research/grounding-dino-tiny"


class GroundingDinoDetector(Detector):
    """Text-prompted boxes; the label is the phrase matched, the caption the same phrase."""

    name = "grounding_dino"

    def __init__(
        self,
        model: str = DEFAULT_MODEL,
        box_threshold: float = 0.35,
        text_threshold: float = 0.25,
        device: str = "cpu",
    ) -> None:
        try:
            import torch
            from transformers import AutoModelForZeroShotObjectDetection, AutoProcessor
        except ImportError as error:
            raise MissingExtraError(
                "the GroundingDINO detector", "vision", f"cannot import {error.name}"
            ) from error
        try:
            self._processor = AutoProcessor.from_pretrained(model, local_files_only=True)
            self._model = AutoModelForZeroShotObjectDetection.from_pretrained(
                model, local_files_only=True
            ).to(device)
        except OSError as error:
            raise MissingExtraError(
                "the GroundingDINO detector",
                "vision",
                f"weights for {model!r} are not on this machine and are never downloaded at run "
                f"time; download them once or pass a local folder as model ({error})",
            ) from error
        self._torch = torch
        self.model_name = model
        self.box_threshold = box_threshold
        self.text_threshold = text_threshold
        self.device = device

    def settings(self) -> dict[str, Any]:
        return {"name": self.name, "model": self.model_name, "box_threshold": self.box_threshold}

    def detect(self, images: CameraImages, phrases: Sequence[str] = ()) -> list[Detection]:
        if not phrases:
            return []
        # GroundingDINO expects lower-case phrases each ending with a full stop.
        text = " ".join(p.lower().rstrip(".") + "." for p in phrases)
        inputs = self._processor(images=images.rgb, text=text, return_tensors="pt").to(self.device)
        with self._torch.no_grad():
            outputs = self._model(**inputs)
        height, width = images.rgb.shape[:2]
        results = self._processor.post_process_grounded_object_detection(
            outputs,
            inputs.input_ids,
            threshold=self.box_threshold,
            text_threshold=self.text_threshold,
            target_sizes=[(height, width)],
        )[0]
        out = []
        for box, score, label in zip(
            results["boxes"], results["scores"], results["labels"], strict=False
        ):
            x0, y0, x1, y1 = (round(float(v)) for v in box)
            x0, y0 = max(0, x0), max(0, y0)
            x1, y1 = min(width, max(x1, x0 + 1)), min(height, max(y1, y0 + 1))
            out.append(
                Detection(
                    str(label), (x0, y0, x1, y1), float(np.clip(float(score), 0, 1)), str(label)
                )
            )
        return out
