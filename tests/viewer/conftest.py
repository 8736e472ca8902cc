"""A real flown run (NMPC, moving obstacles, one episode) shared by the viewer tests."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from skyvln_eval.harness import RunConfig, make_executor, run


@pytest.fixture(scope="session")
def flown_run(tmp_path_factory: pytest.TempPathFactory, sample_dir: Path) -> Path:
    """The run directory of one val_unseen episode flown by the full agent with the NMPC."""
    config = RunConfig.model_validate(
        {
            "system": "viewer test (NMPC)",
            "data": str(sample_dir),
            "splits": ("val_unseen",),
            "limit": 1,
            "mode": "dynamics",
            "workers": 1,
            "executor": "serial",
            "agent": {"name": "skyvln", "hsd": True, "tbma": True, "llm": {"backend": "rule"}},
            "dynamics": {
                "controller": "nmpc",
                "controller_settings": {"compile": "never"},
                "obstacles": {"kind": "crossing", "n_obstacles": 2},
            },
        }
    )
    run_dir = tmp_path_factory.mktemp("viewer") / "run"
    report = run(config, run_dir, executor=make_executor("serial", 1))
    assert report.complete and not report.errors
    return run_dir


@pytest.fixture(scope="session")
def rerun_cli() -> Path:
    """The `rerun` executable of the rerun-sdk wheel (the viewer extra), else skip."""
    pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[viewer]')")
    from skyvln_eval.viewer.deps import rerun_cli_path

    path = rerun_cli_path()
    if not path.is_file() and shutil.which(str(path)) is None:
        pytest.skip(f"the rerun executable is missing at {path}")
    return path
