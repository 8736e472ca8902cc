"""Shipped YAML configurations (controllers, LLM price table, runs, reproduce plans).

They live inside the package so that an installed toolkit finds them; a checkout also
shows them as the top-level ``configs/`` folder (a link to this one).
"""

from importlib import resources
from pathlib import Path


def config_path(*parts: str) -> Path:
    """Path of a shipped config file, e.g. ``config_path("reproduce", "default.yaml")``."""
    return Path(str(resources.files("skyvln_eval.configs").joinpath(*parts)))
