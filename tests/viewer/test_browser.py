"""A real browser opens the served viewer, loads the episode's recording and shows it."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path
from urllib.parse import urlsplit

import cv2
import numpy as np
import pytest

from skyvln_eval.viewer.logs import find_episode_logs
from tests.viewer.cdp import Chromium, find_chromium

#: The viewer's state, as text: it names the recordings it holds and their timelines.
_STATE_JS = (
    "(() => { const h = window._handle; if (!h || h.has_panicked()) return null;"
    " return new TextDecoder('latin1').decode(h.viewer_state()); })()"
)
_LOAD_S = 180.0
_SETTLE_S = 60.0


def _wait_until_loaded(browser: Chromium, names: list[str]) -> str:
    deadline = time.monotonic() + _LOAD_S
    state = ""
    while time.monotonic() < deadline:
        state = browser.evaluate(_STATE_JS) or ""
        if all(name in state for name in names):
            return state
        time.sleep(0.5)
    pytest.fail(f"the viewer did not show the recording in {_LOAD_S} s; state: {state[:300]!r}")


def _settled_screenshot(browser: Chromium) -> bytes:
    """A screenshot once two in a row are identical (software rendering takes a while)."""
    deadline = time.monotonic() + _SETTLE_S
    previous = b""
    while time.monotonic() < deadline:
        time.sleep(2.0)
        shot = browser.screenshot()
        if hashlib.sha256(shot).digest() == hashlib.sha256(previous).digest():
            return shot
        previous = shot
    return previous


@pytest.mark.slow
def test_chromium_shows_the_served_recording(
    flown_run: Path, rerun_cli: Path, tmp_path: Path
) -> None:
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no Chromium found (apt-get install chromium, or set SKYVLN_EVAL_CHROMIUM)")
    from skyvln_eval.viewer import write_recording
    from skyvln_eval.viewer.serve import serve_recordings

    (ref,) = find_episode_logs(flown_run)
    summary = write_recording(ref, tmp_path / "episode.rrd")
    profile = tmp_path / "profile"
    with serve_recordings([summary.path], port=0) as viewer, Chromium(chromium, profile) as browser:
        browser.navigate(viewer.url)
        state = _wait_until_loaded(browser, [summary.recording_id, "decision", "sim_time"])
        shot = _settled_screenshot(browser)
        requests = browser.requests()
        blocked = browser.blocked()
    assert not browser_crashed(state)
    (tmp_path / "viewer.png").write_bytes(shot)
    if target := os.environ.get("SKYVLN_EVAL_VIEWER_SCREENSHOT"):
        Path(target).write_bytes(shot)  # how docs/viewer.png is made
    image = cv2.imdecode(np.frombuffer(shot, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[0] > 500 and image.shape[1] > 1000
    colours = np.unique(image.reshape(-1, 3), axis=0)
    assert image.std() > 20 and len(colours) > 1000, "the screenshot is blank"

    # The page asked the recording's gRPC server for it.
    grpc = urlsplit(viewer.grpc_url.replace("rerun+http", "http", 1))
    asked = [u for u in requests.values() if urlsplit(u).netloc == grpc.netloc]
    assert any(u.endswith("/ReadMessages") for u in asked), sorted(requests.values())
    # Nothing left the machine: every request to another host was blocked by the policy.
    outside = {i: u for i, u in requests.items() if urlsplit(u).hostname not in ("127.0.0.1", None)}
    assert all(blocked.get(i) == "csp" for i in outside), {
        u: blocked.get(i) for i, u in outside.items()
    }


def browser_crashed(state: str) -> bool:
    return not state or "panicked" in state
