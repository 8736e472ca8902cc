"""An independent MCAP implementation reads our files and finds exactly what we find.

The TypeScript reference reader (``@mcap/core``, zstd via ``@mcap/support``, files via
``@mcap/nodejs``) runs under Node on converted sample logs, through the indexes and as a
CRC-checked stream; both must give the same per-topic counts, time range, metadata and
digest over every message as the Python reader. The npm packages are installed into
tests/js/node_modules from the committed lock file when missing.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from skyvln_eval.converters import read_log
from skyvln_eval.converters import topics as t
from skyvln_eval.errors import McapLogError
from tests.conftest import REPO
from tests.converters.conftest import ConvertedSample, chunk_payload_span

JS_DIR = REPO / "tests" / "js"
PACKAGES = ("@mcap/core", "@mcap/nodejs", "@mcap/support")


@pytest.fixture(scope="module")
def node() -> str:
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip(
            "Node.js and npm are not installed: the cross-check against the TypeScript "
            "MCAP reader (@mcap/core) needs them (CI has them)"
        )
    if not all((JS_DIR / "node_modules" / p / "package.json").is_file() for p in PACKAGES):
        result = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"],
            cwd=JS_DIR,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert result.returncode == 0, (
            f"npm ci failed in {JS_DIR}:\n{result.stdout}\n{result.stderr}"
        )
    return node


def read_with_node(node: str, paths: list[Path]) -> dict[str, Any]:
    result = subprocess.run(
        [node, str(JS_DIR / "read_mcap.mjs"), *map(str, paths)],
        cwd=JS_DIR,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    out: dict[str, Any] = json.loads(result.stdout)
    return out


def test_typescript_reader_agrees_on_every_sample_log(
    node: str, converted_sample: ConvertedSample
) -> None:
    paths = sorted(converted_sample.out_dir.rglob("*.mcap"))
    assert len(paths) == sum(len(e) for e in converted_sample.episodes.values())
    results = read_with_node(node, paths)
    assert set(results) == {str(p) for p in paths}
    for path in paths:
        theirs = results[str(path)]
        assert "error" not in theirs, f"{path}: {theirs.get('error')}"
        log = read_log(path)
        ours = log.summary().as_json()
        assert theirs["indexed"]["topic_counts"] == ours["topic_counts"], path
        for how in ("indexed", "streamed"):
            got = {k: theirs[how][k] for k in ours}
            assert got == ours, f"{path} ({how} read)"
        assert theirs["indexed"]["header"] == {"profile": log.profile, "library": log.library}
        assert theirs["indexed"]["schemas"] == {c.topic: c.schema_name for c in log.channels}
        assert theirs["indexed"]["statistics_message_count"] == str(len(log.messages))
        assert t.EPISODE_METADATA in theirs["indexed"]["metadata"]


def test_typescript_reader_rejects_a_damaged_chunk_as_we_do(
    node: str, converted_sample: ConvertedSample, tmp_path: Path
) -> None:
    """Guard: the cross-check can fail. A flipped byte inside the chunk is caught by both."""
    source = next(converted_sample.out_dir.rglob("*.mcap"))
    data = bytearray(source.read_bytes())
    start, end = chunk_payload_span(bytes(data))
    data[(start + end) // 2] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(McapLogError):
        read_log(damaged)
    theirs = read_with_node(node, [damaged])[str(damaged)]
    assert "error" in theirs, theirs
