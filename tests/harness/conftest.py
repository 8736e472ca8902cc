"""Small run configurations on the bundled sample for the harness tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.harness import RunConfig


@pytest.fixture
def small_config(sample_dir: Path):  # type: ignore[no-untyped-def]
    """A factory of small run configs: 2 episodes per split unless told otherwise."""

    def make(**overrides: Any) -> RunConfig:
        settings: dict[str, Any] = {
            "system": "test system",
            "data": str(sample_dir),
            "splits": ("val_unseen",),
            "limit": 2,
            "workers": 1,
            "executor": "serial",
        }
        settings.update(overrides)
        if settings.get("mode") == "dynamics":
            dynamics = dict(settings.get("dynamics", {}))
            dynamics.setdefault("controller_settings", {"compile": "never"})
            settings["dynamics"] = dynamics
        return RunConfig.model_validate(settings)

    return make
