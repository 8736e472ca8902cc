"""The benchmarks still run: each of the quick ones on a tiny size, as a user runs it.

Their figures are not checked (timings belong to benchmarks, not tests); what is checked
is that the script runs to its end and prints its comparison. A benchmark that reaches
for a renamed attribute otherwise breaks unnoticed until someone needs its figures.
The NMPC benchmark runs its own controller only (the IPOPT and do-mpc baselines take
minutes, HPIPM's compilation about 40 s). Left out: the real-LLM benchmark (it needs the
local model), the language benchmark (every split three times), and those that build
the full synthetic dataset first (harness, load_split, convert, world_load).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

QUICK = {
    "commander.py": (["--limit", "2", "--splits", "val_seen"], "blind beacon (answers only)"),
    "flight_loop.py": (["--repeat", "1"], "whole / solve"),
    "render.py": (["--poses", "2", "--reference-poses", "1", "--worlds", "1"], "faster than"),
    "detector.py": (["--decisions", "2", "--repeat", "1"], "speed-up"),
    "agent_sample.py": (["--splits", "val_seen", "--limit", "2"], "all splits:"),
    "city_tile.py": (["--seeds", "1"], "baseline"),
    "nmpc.py": (
        ["--steps", "20", "--skip", "naive,do-mpc,ours_hpipm,ours_interpreted,ours_converged"],
        "aims: ",
    ),
    "metrics.py": (
        ["--episodes", "200", "--baseline", "20", "--resamples", "50", "--bootstrap-n", "50"],
        "ratio",
    ),
}


@pytest.mark.parametrize("script", sorted(QUICK))
def test_the_benchmark_runs_and_prints_its_comparison(script: str) -> None:
    arguments, expected = QUICK[script]
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), *arguments],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert expected in done.stdout, done.stdout[-2000:]
