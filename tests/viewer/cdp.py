"""Headless Chromium driven over the DevTools protocol on a pipe (no extra package).

Chromium's ``--remote-debugging-pipe`` reads protocol commands on file descriptor 3 and
writes replies and events on descriptor 4, each a JSON text ended by a NUL byte; this
module starts the browser with those two descriptors and speaks that protocol: enough to
open a page, watch its network requests, evaluate JavaScript and take screenshots.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import signal
import time
from pathlib import Path
from types import TracebackType
from typing import Any

#: Flags that work here as root in a container: no sandbox, no GPU (software WebGL), and
#: none of Chromium's own background traffic. The viewer's WebAssembly runs on V8's
#: baseline compiler only: optimising the large module competes for the test machine's
#: two cores (the recording showed after 28 s instead of 37 s).
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--enable-unsafe-swiftshader",
    "--remote-debugging-pipe",
    "--js-flags=--liftoff-only",
)


def find_chromium() -> str | None:
    """``$SKYVLN_EVAL_CHROMIUM``, else a Chromium or Chrome on the PATH."""
    if path := os.environ.get("SKYVLN_EVAL_CHROMIUM"):
        return path
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if found := shutil.which(name):
            return found
    return None


class Chromium:
    """One headless browser with one page; use it as a context manager."""

    def __init__(self, executable: str, profile_dir: Path, size: tuple[int, int] = (1600, 900)):
        commands_r, self._commands_w = os.pipe()
        self._events_r, events_w = os.pipe()
        self.log_path = profile_dir.parent / "chromium.log"
        argv = [
            executable,
            *FLAGS,
            f"--user-data-dir={profile_dir}",
            f"--window-size={size[0]},{size[1]}",
            "about:blank",
        ]
        actions = [
            (os.POSIX_SPAWN_OPEN, 0, os.devnull, os.O_RDONLY, 0),
            (os.POSIX_SPAWN_OPEN, 1, str(self.log_path), os.O_WRONLY | os.O_CREAT, 0o644),
            (os.POSIX_SPAWN_DUP2, 1, 2),
            (os.POSIX_SPAWN_DUP2, commands_r, 3),
            (os.POSIX_SPAWN_DUP2, events_w, 4),
        ]
        # posix_spawn, not Popen(preexec_fn=...): safe in a process that runs threads.
        self.pid = os.posix_spawn(
            executable, argv, dict(os.environ), file_actions=actions, setpgroup=0
        )
        os.close(commands_r)
        os.close(events_w)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict[str, Any]] = []
        self.session = ""

    def __enter__(self) -> Chromium:
        targets = self.send("Target.getTargets")["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        attached = self.send(
            "Target.attachToTarget", {"targetId": page["targetId"], "flatten": True}
        )
        self.session = attached["sessionId"]
        for domain in ("Page", "Network", "Runtime"):
            self.send(f"{domain}.enable", session=True)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(OSError, TimeoutError, EOFError, RuntimeError):
            self.send("Browser.close", timeout_s=10)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            done, _ = os.waitpid(self.pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.1)
        else:
            os.killpg(self.pid, signal.SIGKILL)  # the group this browser was started in
            os.waitpid(self.pid, 0)
        for fd in (self._commands_w, self._events_r):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _read(self, timeout_s: float) -> dict[str, Any] | None:
        while b"\0" not in self._buffer:
            ready, _, _ = select.select([self._events_r], [], [], max(0.0, timeout_s))
            if not ready:
                return None
            chunk = os.read(self._events_r, 1 << 20)
            if not chunk:
                raise EOFError("Chromium closed its DevTools pipe")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        message: dict[str, Any] = json.loads(raw)
        return message

    def send(
        self,
        method: str,
        params: dict[str, Any] | None = None,
        session: bool = False,
        timeout_s: float = 60.0,
    ) -> dict[str, Any]:
        """Send one command and return its result; events that arrive meanwhile are kept."""
        self._next_id += 1
        command: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            command["sessionId"] = self.session
        os.write(self._commands_w, json.dumps(command).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            message = self._read(deadline - time.monotonic())
            if message is None:
                continue
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                result: dict[str, Any] = message.get("result", {})
                return result
            self.events.append(message)
        raise TimeoutError(f"no reply to {method} in {timeout_s} s")

    def navigate(self, url: str) -> None:
        self.send("Page.navigate", {"url": url}, session=True)

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (None when it throws)."""
        reply = self.send(
            "Runtime.evaluate", {"expression": expression, "returnByValue": True}, session=True
        )
        if "exceptionDetails" in reply:
            return None
        return reply.get("result", {}).get("value")

    def screenshot(self) -> bytes:
        reply = self.send("Page.captureScreenshot", {"format": "png"}, session=True)
        return base64.b64decode(reply["data"])

    def requests(self) -> dict[str, str]:
        """URL of every request the page started, by request id."""
        return {
            e["params"]["requestId"]: e["params"]["request"]["url"]
            for e in self.events
            if e.get("method") == "Network.requestWillBeSent"
        }

    def blocked(self) -> dict[str, str]:
        """Why each request that did not load failed (``csp`` when the policy blocked it)."""
        return {
            e["params"]["requestId"]: str(
                e["params"].get("blockedReason") or e["params"].get("errorText")
            )
            for e in self.events
            if e.get("method") == "Network.loadingFailed"
        }
