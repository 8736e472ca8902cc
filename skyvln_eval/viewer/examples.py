"""Example recordings for ``reproduce``: a few episodes of each system, as ``.rrd`` files.

Without the viewer extra nothing is written and the note says how to get them: the
tables and figures never depend on Rerun being installed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from skyvln_eval.errors import MissingExtraError
from skyvln_eval.harness.plan import slug
from skyvln_eval.viewer.logs import LOGS_DIR, EpisodeLogRef
from skyvln_eval.viewer.recording import write_recording

#: How SUMMARY.md tells a reader to open a recording.
OPEN_COMMAND = "skyvln-eval view {path}"


def write_examples(
    chosen: Mapping[str, tuple[Path, Sequence[tuple[str, str]]]], out_dir: Path
) -> tuple[dict[str, Path], list[str]]:
    """``chosen``: system label -> (run directory, [(split, episode_id), ...]).

    Returns the files by name (``<system>__<split>__<episode>.rrd``) and notes for the
    summary. A recording already written is kept: a run's finished episodes never change.
    """
    files: dict[str, Path] = {}
    notes: list[str] = []
    for label, (run_dir, keys) in chosen.items():
        for split, episode_id in keys:
            name = f"{slug(label)}__{split}__{episode_id}.rrd"
            path = out_dir / name
            log = run_dir / LOGS_DIR / split / f"{episode_id}.mcap"
            if not log.is_file():
                notes.append(f"{label}: no run MCAP for {split}/{episode_id} (logs were off)")
                continue
            if not path.is_file():
                try:
                    write_recording(EpisodeLogRef(log, split, episode_id), path)
                except MissingExtraError as error:
                    return files, [f"Episode recordings were not written: {error}."]
            files[name] = path
    return files, notes
