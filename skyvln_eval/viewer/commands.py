"""``skyvln-eval view``: build episode recordings from run MCAPs, save them, serve them.

The CLI parses the options and calls :func:`run_view`; the library functions
(:func:`build_recordings`, :func:`merge_recordings`, :func:`~.serve.serve_recordings`) do the
work and are usable from Python too.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import typer

from skyvln_eval.errors import ConfigError, McapLogError
from skyvln_eval.interrupts import terminate_like_ctrl_c
from skyvln_eval.viewer import entities as e
from skyvln_eval.viewer.deps import rerun_cli_path
from skyvln_eval.viewer.logs import EpisodeLogRef, find_episode_logs, unlogged_note
from skyvln_eval.viewer.privacy import USER_OPT_OUT, rerun_environment
from skyvln_eval.viewer.recording import RecordingSummary, write_recording
from skyvln_eval.viewer.serve import serve_recordings

#: Serving more recordings than this at once is slow in a browser; say so.
MANY_RECORDINGS = 50
#: How an .rrd file begins: Rerun's stream header, "RRF" and a format version ("RRF2" from
#: the installed Rerun).
RRD_MAGIC = b"RRF"


def recording_file_names(refs: Sequence[EpisodeLogRef]) -> list[str]:
    """A file name per episode log, all different: ``<split>__<id>.rrd``, after the run's
    folder name where runs of one folder hold the same episode (a folder of runs, e.g. a
    reproduction's, flies each episode once per system: one file replaced the other), and
    numbered where even that is the same."""
    plain = [f"{ref.split}__{ref.episode_id}" for ref in refs]
    shared = Counter(plain)
    named = [
        f"{ref.run_name}__{name}" if shared[name] > 1 and ref.run_name else name
        for ref, name in zip(refs, plain, strict=True)
    ]
    total, seen = Counter(named), Counter[str]()
    unique = []
    for name in named:
        seen[name] += 1
        unique.append(name if total[name] == 1 else f"{name}__{seen[name]}")
    return [f"{name}.rrd" for name in unique]


def build_recordings(
    refs: Sequence[EpisodeLogRef],
    out_dir: Path,
    on_done: Callable[[RecordingSummary], None] | None = None,
    on_damaged: Callable[[McapLogError], None] | None = None,
) -> list[RecordingSummary]:
    """One ``.rrd`` per episode in ``out_dir``, built one after the other (streaming each).

    A damaged log stops the batch unless ``on_damaged`` is given: then it is handed the
    error and the batch goes on without that episode."""
    summaries = []
    for ref, name in zip(refs, recording_file_names(refs), strict=True):
        try:
            summary = write_recording(ref, out_dir / name)
        except McapLogError as error:
            if on_damaged is None:
                raise
            on_damaged(error)
            continue
        summaries.append(summary)
        if on_done is not None:
            on_done(summary)
    return summaries


def merge_recordings(paths: Sequence[Path], out: Path) -> None:
    """Several ``.rrd`` files as one (each episode stays its own recording), atomically."""
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    command = [str(rerun_cli_path()), "rrd", "merge", *map(str, paths), "-o", str(tmp)]
    result = subprocess.run(
        command,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        env=rerun_environment(),
        check=False,
    )
    if result.returncode != 0 or not tmp.is_file():
        tmp.unlink(missing_ok=True)
        raise ConfigError(f"rerun rrd merge failed for {out}: {result.stderr.strip()[-1000:]}")
    tmp.replace(out)


def image_counts(rows: Mapping[str, int]) -> dict[str, int]:
    """Images of the flight per kind, from a recording's rows per entity (the map tile,
    one image drawn under everything, is not one of them)."""
    camera_views = sum(
        n
        for path, n in rows.items()
        if path.startswith(f"{e.CAMERA_DETECTIONS}/") and path.endswith("/image")
    )
    return {
        "observation": rows.get(e.CAMERA_OBSERVATION, 0),
        "camera view": camera_views,
        "ground-truth view": rows.get(e.CAMERA_GT_OBSERVATION, 0),
    }


def describe(summary: RecordingSummary, show_path: bool = True) -> str:
    """One line on what a recording holds, in the terms of its log: an agent's decisions
    for a run log, ground-truth views for an episode log; images of every kind."""
    rows = summary.rows
    images = image_counts(rows)
    kinds = ", ".join(f"{n} {kind}" for kind, n in images.items() if n)
    parts = [
        f"{summary.decisions} decision(s)"
        if summary.run_log
        else f"{summary.gt_views} ground-truth view(s) (an episode log: no agent flew it)",
        f"{sum(images.values())} image(s)" + (f" ({kinds})" if kinds else ""),
    ]
    if summary.run_log:
        parts += [
            f"{rows.get(e.LLM_LOG, 0)} LLM exchange(s)",
            f"{rows.get(e.WORLD_DRONE, 0)} pose(s)",
            f"{rows.get(e.WORLD_OBSTACLES, 0)} obstacle sample(s)",
        ]
    if summary.merged_decisions:
        parts.append(
            f"{summary.merged_decisions} decision(s) at a time another has: merged on the "
            "decision timeline"
        )
    where = f" -> {summary.path}" if show_path else ""
    return f"{summary.episode.key}: {', '.join(parts)}{where}"


def _save(
    refs: Sequence[EpisodeLogRef],
    save: Path,
    work: Path,
    on_damaged: Callable[[McapLogError], None],
) -> list[Path]:
    if save.suffix == ".rrd":
        if len(refs) == 1:
            summary = write_recording(refs[0], save)
            typer.echo(describe(summary))
            return [save]
        built = build_recordings(refs, work, lambda s: typer.echo(describe(s, False)), on_damaged)
        if not built:
            return []
        save.parent.mkdir(parents=True, exist_ok=True)
        merge_recordings([s.path for s in built], save)
        typer.echo(f"saved {len(built)} recording(s) in {save}")
        return [save]
    built = build_recordings(refs, save, lambda s: typer.echo(describe(s)), on_damaged)
    return [s.path for s in built]


def _serve(paths: Sequence[Path], port: int) -> None:
    with serve_recordings(paths, port=port) as viewer:
        try:  # from the first line on: a Ctrl-C at any moment stops the server cleanly
            typer.echo(f"Rerun web viewer (local only, analytics off): {viewer.url}")
            typer.echo("Open it in a browser; Ctrl-C stops the server.")
            while viewer.process.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            typer.echo("stopped")
            return
        typer.echo(f"the rerun process stopped:\n{viewer.log_tail()}", err=True)
        raise typer.Exit(1)


def run_view(
    target: Path,
    episodes: Sequence[str],
    save: Path | None,
    serve: bool,
    port: int,
) -> None:
    """The ``view`` command (see ``skyvln-eval view --help``)."""
    with terminate_like_ctrl_c():  # the server stopped, the temporary recordings removed
        _view(target, episodes, save, serve, port)


def _view(target: Path, episodes: Sequence[str], save: Path | None, serve: bool, port: int) -> None:
    if target.suffix == ".rrd":
        if episodes or save:
            raise ConfigError(f"{target} is already a recording: --episode and --save do not apply")
        if not target.is_file():
            raise ConfigError(f"{target}: no such recording")
        with target.open("rb") as handle:
            magic = handle.read(len(RRD_MAGIC))
        if magic != RRD_MAGIC:  # else the viewer is served with nothing in it, and no error
            raise ConfigError(
                f"{target}: not a Rerun recording (it does not start as an .rrd file does)"
            )
        _serve([target], port)
        return
    refs = find_episode_logs(target, episodes)
    unlogged = None if episodes else unlogged_note(target)
    if unlogged is not None:  # a batch says what it leaves out: here, what it cannot show
        typer.echo(f"not shown: {unlogged}", err=True)
    damaged: list[McapLogError] = []

    def skip(error: McapLogError) -> None:  # one damaged log of many: the rest are shown
        damaged.append(error)
        typer.echo(f"skipped: {error}", err=True)

    with tempfile.TemporaryDirectory(prefix="skyvln-view-") as work:
        if save is not None:
            paths = _save(refs, save, Path(work), skip)
        else:
            built = build_recordings(
                refs, Path(work), lambda s: typer.echo(describe(s, False)), skip
            )
            paths = [s.path for s in built]
        if not paths:  # every log damaged: nothing to show
            raise damaged[0]
        if damaged:
            typer.echo(
                f"{len(damaged)} of {len(refs)} episode log(s) skipped as damaged "
                "(`skyvln-eval validate` checks them)",
                err=True,
            )
        if save is None or serve:
            if len(paths) > MANY_RECORDINGS:
                typer.echo(f"serving {len(paths)} recordings; --episode picks a few", err=True)
            _serve(paths, port)
        else:
            typer.echo(open_hint(paths, save))
    if damaged:  # shown what could be, and said: the exit code says it too
        raise typer.Exit(1)


def open_hint(paths: Sequence[Path], save: Path) -> str:
    """How to open what ``--save`` wrote: the file, or one of a folder's files (``view``
    takes one recording, ``rerun`` several), named as a shell would need them."""
    first = shlex.quote(str(paths[0]))
    if len(paths) == 1:
        how = f"open with: skyvln-eval view {first}  (or `rerun {first}`"
    else:
        every = f"{shlex.quote(str(save))}/*.rrd"
        how = f"open one with: skyvln-eval view {first}  (or all: `rerun {every}`"
    return f"{how}; `{USER_OPT_OUT}` turns Rerun's analytics off for that)"
