"""The synthetic AVDN-format dataset: routes, pilot, dialogs, builder and cache."""

from skyvln_eval.worlds.sample.build import (
    FULL_SPEC,
    SAMPLE_SPEC,
    SPECS,
    DatasetSpec,
    build_dataset,
)
from skyvln_eval.worlds.sample.cache import cache_root, ensure_dataset, ensure_sample

__all__ = [
    "FULL_SPEC",
    "SAMPLE_SPEC",
    "SPECS",
    "DatasetSpec",
    "build_dataset",
    "cache_root",
    "ensure_dataset",
    "ensure_sample",
]
