"""What a conversion left out, kept beside the manifest in ``left_out.json``.

The manifest lists only the logs written. A split converted with ``--skip-invalid``, or
one whose episodes failed, lacks some episodes: this file says which and why, so the
folder itself tells (``skyvln-eval validate`` prints it), not only the conversion's
stderr. Every conversion writes it, empty when nothing was left out, so a re-run
replaces what an earlier one recorded.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Final, Literal, get_args

from skyvln_eval.avdn.constants import ANNOTATIONS_DIR, annotation_file_name
from skyvln_eval.errors import FormatVersionError, McapLogError
from skyvln_eval.fileio import atomic_write_bytes, sha256_bytes

LEFT_OUT_NAME: Final = "left_out.json"
LEFT_OUT_VERSION: Final = 1
LeftOutKind = Literal["invalid_record", "incomplete_trajectory", "failed_episode"]


@dataclass(frozen=True)
class LeftOut:
    """One record, trajectory or episode that has no log in the folder, and why.

    ``record_index`` is the record's 0-based position in the annotation file (invalid
    records only); ``episode_id`` is None when the record names none.
    """

    kind: LeftOutKind
    episode_id: str | None
    record_index: int | None
    reasons: tuple[str, ...]

    def __str__(self) -> str:
        what = self.kind.replace("_", " ")
        if self.record_index is not None:
            what += f" {self.record_index}"
        if self.episode_id is not None:
            what += f" (episode {self.episode_id})"
        return f"{what}: {'; '.join(self.reasons)}"


def left_out_bytes(split: str, mode: str, entries: Sequence[LeftOut]) -> bytes:
    document = {
        "format_version": LEFT_OUT_VERSION,
        "split": split,
        "mode": mode,
        # record_index counts the records of this file, from 0.
        "source": f"{ANNOTATIONS_DIR}/{annotation_file_name(split)}",
        "left_out": [{**asdict(e), "reasons": list(e.reasons)} for e in entries],
    }
    # ASCII with escapes: any text a record held can be written, and strict JSON (no NaN).
    return (json.dumps(document, indent=1, allow_nan=False) + "\n").encode("ascii")


def write_left_out(path: str | Path, split: str, mode: str, entries: Sequence[LeftOut]) -> str:
    """Write the file; returns its SHA-256 (the manifest records it)."""
    data = left_out_bytes(split, mode, entries)
    atomic_write_bytes(path, data)
    return sha256_bytes(data)


def read_left_out(path: str | Path) -> list[LeftOut]:
    """The entries of a ``left_out.json``; raises McapLogError (unreadable) or
    FormatVersionError."""
    try:
        document = json.loads(Path(path).read_bytes())
    except (OSError, ValueError) as exc:
        raise McapLogError(str(path), f"cannot be read as JSON: {exc}") from exc
    found = document.get("format_version") if isinstance(document, dict) else None
    if found != LEFT_OUT_VERSION:
        raise FormatVersionError(
            str(path),
            found,
            LEFT_OUT_VERSION,
            "Convert the split again with this version: `skyvln-eval convert ...`.",
        )
    entries = document.get("left_out")
    if not isinstance(entries, list):
        raise McapLogError(str(path), "'left_out' is not a list")
    return [_entry(item, path, k) for k, item in enumerate(entries)]


def _entry(item: Any, path: str | Path, index: int) -> LeftOut:
    try:
        kind, reasons = item["kind"], item["reasons"]
        episode_id, record_index = item["episode_id"], item["record_index"]
    except (KeyError, TypeError) as exc:
        raise McapLogError(str(path), f"left_out[{index}] lacks {exc}") from exc
    if (
        kind not in get_args(LeftOutKind)
        or not (isinstance(reasons, list) and all(isinstance(r, str) for r in reasons))
        or not (episode_id is None or isinstance(episode_id, str))
        or not (record_index is None or type(record_index) is int)
    ):
        raise McapLogError(str(path), f"left_out[{index}] is not a valid entry: {item!r}")
    return LeftOut(kind, episode_id, record_index, tuple(reasons))
