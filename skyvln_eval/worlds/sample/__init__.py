"""The synthetic AVDN-format dataset: routes, pilot, dialogs, builder and cache."""

from skyvln_eval.worlds.sample.build import (
    FULL_SPEC,
    SAMPLE_SPEC,
    SPECS,
    DatasetSpec,
    build_dataset,
)
from skyvln_eval.worlds.sample.cache import (
    cache_root,
    ensure_dataset,
    ensure_sample,
    write_dataset,
)
from skyvln_eval.worlds.sample.dialogs import (
    DIALOG_VERSION,
    AnswerFacts,
    Utterance,
    commander_answer,
    render_trajectory,
)
from skyvln_eval.worlds.sample.phrasebook import (
    FAMILIES,
    SPLIT_FAMILIES,
    held_out_families,
    seen_families,
)
from skyvln_eval.worlds.sample.sources import (
    DialogSources,
    TrajectoryDialog,
    load_dialogs,
    rephrase_records,
)

__all__ = [
    "DIALOG_VERSION",
    "FAMILIES",
    "FULL_SPEC",
    "SAMPLE_SPEC",
    "SPECS",
    "SPLIT_FAMILIES",
    "AnswerFacts",
    "DatasetSpec",
    "DialogSources",
    "TrajectoryDialog",
    "Utterance",
    "build_dataset",
    "cache_root",
    "commander_answer",
    "ensure_dataset",
    "ensure_sample",
    "held_out_families",
    "load_dialogs",
    "render_trajectory",
    "rephrase_records",
    "seen_families",
    "write_dataset",
]
