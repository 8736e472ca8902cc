"""Seeds of a run's random choices, derived from the run's seed and what they are for.

Each is a function of names only (never of run order or worker count), so an episode
flies the same however the run is split across processes and resumed.
"""

from __future__ import annotations

import hashlib


def derived_seed(*parts: object) -> int:
    """A 31-bit seed from any parts: independent of run order and worker count."""
    digest = hashlib.sha256("/".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:4], "big") & 0x7FFFFFFF


def run_episode_seed(run_seed: int, split: str, episode_id: str) -> int:
    """The seed of one episode of a run: its agent's, its obstacles' and its commander's
    seeds derive from it."""
    return derived_seed(run_seed, split, episode_id)
