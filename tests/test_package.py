"""Package hygiene: light imports, lint, formatting and types."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import REPO, modules_loaded_by

HEAVY = ("ray", "transformers", "torch", "openai", "rerun")


def test_importing_the_toolkit_imports_no_optional_heavy_dependency() -> None:
    code = (
        "import sys, skyvln_eval, skyvln_eval.avdn, skyvln_eval.worlds, skyvln_eval.cli\n"
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]"


def test_a_run_does_not_import_the_log_validator_s_json_schema_library() -> None:
    """jsonschema (with its URI grammar, compiled on import) takes up to 2 s to import: only
    checking a log needs it, not every CLI start and every worker of a run."""
    assert modules_loaded_by("skyvln_eval.harness", ("jsonschema",)) == []


def _tool(name: str) -> list[str]:
    # The test extra installs ruff and mypy into this interpreter's environment.
    return [sys.executable, "-m", name]


def test_ruff_lint_is_clean() -> None:
    result = subprocess.run(
        [*_tool("ruff"), "check", "."], capture_output=True, text=True, cwd=REPO
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format_is_clean() -> None:
    result = subprocess.run(
        [*_tool("ruff"), "format", "--check", "."], capture_output=True, text=True, cwd=REPO
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_is_clean() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "mypy"], capture_output=True, text=True, cwd=REPO
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_a_runs_outputs_load_from_the_package_facades() -> None:
    # The README's "In Python / Jupyter" names these; read_scores lived only in
    # skyvln_eval.metrics.scores_io.
    import skyvln_eval.harness as harness
    import skyvln_eval.metrics as metrics
    import skyvln_eval.reports as reports

    for module, names in (
        (harness, ["run_results"]),
        (metrics, ["read_results", "read_scores", "score_results", "summarise"]),
        (reports, ["paper_table", "to_markdown"]),
    ):
        assert set(names) <= set(module.__all__), module.__name__
