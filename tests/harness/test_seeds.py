"""A run's seeds are functions of names only: the same in every process, whatever its
hash seed, run order or worker count."""

from __future__ import annotations

import os
import subprocess
import sys

from skyvln_eval.harness.seeds import derived_seed, run_episode_seed
from tests.conftest import REPO

PRINT = (
    "from skyvln_eval.harness.seeds import derived_seed, run_episode_seed\n"
    "print(derived_seed(0, 'obstacles', 3), run_episode_seed(7, 'val_seen', '9101__8_1'))\n"
)


def test_seeds_are_the_same_in_every_process() -> None:
    # Python's hash() of text differs between processes: a seed built on it would give
    # each worker its own obstacles and detector noise.
    here = f"{derived_seed(0, 'obstacles', 3)} {run_episode_seed(7, 'val_seen', '9101__8_1')}"
    for hash_seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed, "PYTHONPATH": str(REPO)}
        done = subprocess.run(
            [sys.executable, "-c", PRINT], env=env, capture_output=True, text=True, check=True
        )
        assert done.stdout.strip() == here


def test_seeds_tell_their_parts_apart_and_fit_31_bits() -> None:
    seeds = {
        run_episode_seed(run, split, episode)
        for run in (0, 1)
        for split in ("val_seen", "val_unseen")
        for episode in ("9101__8_1", "9101__8_2")
    }
    assert len(seeds) == 8 and all(0 <= s < 2**31 for s in seeds)
    assert derived_seed(1, "ab") != derived_seed(1, "a", "b")  # parts joined with '/', not glued
