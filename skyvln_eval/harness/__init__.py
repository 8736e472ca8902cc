"""Running agents on episodes: the official-mode loop (the full harness builds on it)."""

from skyvln_eval.harness.official_loop import (
    OfficialRollout,
    official_success,
    run_official_episode,
)

__all__ = ["OfficialRollout", "official_success", "run_official_episode"]
