"""Serve recordings in Rerun's bundled web viewer, on 127.0.0.1 only, with nothing sent out.

Three parts, all bound to the loopback address:

1. the ``rerun`` executable of the rerun-sdk wheel, started with ``--serve-web --bind
   127.0.0.1`` on the ``.rrd`` files: a gRPC server holding the recordings and an HTTP
   server for the viewer's page and Wasm (analytics off: :mod:`.privacy`);
2. a small HTTP proxy in front of that page, on the port the user chose, which adds a
   content security policy: the page may load only from itself and connect only to the
   gRPC server. The web viewer otherwise reports usage, asks GitHub for the latest
   release, loads example lists and web fonts from the internet;
3. the URL to open, which names the gRPC server as the recording source.

(The SDK's own ``serve_grpc`` / ``serve_web_viewer`` listen on every interface, which
would expose private recordings to the network; the executable takes ``--bind``.)
"""

from __future__ import annotations

import ctypes
import http.client
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, ClassVar
from urllib.parse import quote

from skyvln_eval.errors import SkyvlnError
from skyvln_eval.viewer.deps import rerun_cli_path
from skyvln_eval.viewer.privacy import rerun_environment

HOST = "127.0.0.1"
DEFAULT_PORT = 9090
#: Headers of the upstream response that the proxy does not pass on (it re-frames the body).
_HOP_BY_HOP = frozenset({"connection", "transfer-encoding", "content-length", "keep-alive"})
#: Headers ``send_response`` writes itself: forwarded too, each would be there twice.
_SENT_BY_THE_PROXY = frozenset({"server", "date"})
_STARTUP_S = 60.0
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


class ViewerServeError(SkyvlnError):
    """The web viewer could not be started (port taken, executable failed)."""


def content_security_policy(grpc_port: int) -> str:
    """What the page may load and connect to: itself and the recordings' gRPC server."""
    return "; ".join(
        [
            "default-src 'self'",
            "script-src 'self' 'unsafe-inline' 'wasm-unsafe-eval'",
            "style-src 'self' 'unsafe-inline'",
            "img-src 'self' data: blob:",
            "font-src 'self' data:",
            "media-src 'self' data: blob:",
            "worker-src 'self' blob:",
            f"connect-src 'self' http://{HOST}:{grpc_port}",
            "object-src 'none'",
            "frame-src 'none'",
            "base-uri 'none'",
            "form-action 'none'",
        ]
    )


def free_port() -> int:
    """A TCP port free on the loopback address now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((HOST, 0))
        return int(probe.getsockname()[1])


def _wait_for_port(port: int, process: subprocess.Popen[bytes], deadline: float) -> bool:
    while time.monotonic() < deadline and process.poll() is None:
        try:
            with socket.create_connection((HOST, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.1)
    return False


class _ProxyHandler(BaseHTTPRequestHandler):
    """GET/HEAD forwarded to the viewer's page server, with the security policy added."""

    upstream_port: ClassVar[int] = 0
    policy: ClassVar[str] = ""

    def _forward(self, send_body: bool) -> None:
        upstream = http.client.HTTPConnection(HOST, self.upstream_port, timeout=60)
        try:
            upstream.request(self.command, self.path, headers={"Accept-Encoding": "identity"})
            response = upstream.getresponse()
            self.send_response(response.status, response.reason)
            for name, value in response.getheaders():
                if name.lower() not in _HOP_BY_HOP | _SENT_BY_THE_PROXY:
                    self.send_header(name, value)
            self.send_header("Content-Security-Policy", self.policy)
            self.send_header("Referrer-Policy", "no-referrer")
            self.end_headers()
            if send_body:
                shutil.copyfileobj(response, self.wfile, 1 << 20)
        except OSError:
            self.close_connection = True  # the browser went away, or the viewer stopped
        finally:
            upstream.close()

    def do_GET(self) -> None:
        self._forward(send_body=True)

    def do_HEAD(self) -> None:
        self._forward(send_body=False)

    def log_message(self, format: str, *args: object) -> None:  # quiet: no access log
        return


@dataclass
class ServedViewer:
    """A running web viewer; :meth:`close` (or leaving the ``with`` block) stops it."""

    url: str
    grpc_url: str
    port: int
    process: subprocess.Popen[bytes]
    proxy: ThreadingHTTPServer
    log_path: Path
    _log_file: BinaryIO
    _thread: threading.Thread = field(repr=False)

    def __enter__(self) -> ServedViewer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        self.proxy.shutdown()
        self.proxy.server_close()
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)
        self._log_file.close()
        shutil.rmtree(self.log_path.parent, ignore_errors=True)

    def log_tail(self, lines: int = 20) -> str:
        text = self.log_path.read_text(encoding="utf-8", errors="replace")
        return "\n".join(text.splitlines()[-lines:])


def _start_proxy(
    process: subprocess.Popen[bytes], port: int, page_port: int, grpc_port: int, log_path: Path
) -> ThreadingHTTPServer:
    """Wait for the executable's two servers, then listen on ``port`` in front of the page."""
    deadline = time.monotonic() + _STARTUP_S
    if not all(_wait_for_port(p, process, deadline) for p in (grpc_port, page_port)):
        tail = log_path.read_text(encoding="utf-8", errors="replace")[-2000:]
        raise ViewerServeError(f"the rerun web viewer did not start:\n{tail}")
    handler = type(
        "ProxyHandler",
        (_ProxyHandler,),
        {"upstream_port": page_port, "policy": content_security_policy(grpc_port)},
    )
    try:
        proxy = ThreadingHTTPServer((HOST, port), handler)
    except OSError as error:
        raise ViewerServeError(f"cannot listen on {HOST}:{port}: {error.strerror}") from error
    proxy.daemon_threads = True
    return proxy


def _terminated_with(parent_pid: int) -> Callable[[], None]:
    """What the executable's process runs before it starts (Linux): it is sent SIGTERM
    when the thread that started it dies, however that dies. A toolkit killed with
    SIGKILL runs no clean-up, and a rerun server left behind would keep its ports and a
    core busy. If the toolkit is already gone, the process ends at once."""
    # Looked up here, before the fork: the child only makes the call (no dynamic loading
    # between fork and exec, where another thread of the parent may hold the loader's lock).
    prctl = ctypes.CDLL(None, use_errno=True).prctl

    def arrange() -> None:
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # died before the request took effect
            os._exit(1)

    return arrange


def serve_recordings(
    rrd_paths: Sequence[str | Path],
    port: int = DEFAULT_PORT,
    memory_limit: str = "25%",
) -> ServedViewer:
    """Serve ``.rrd`` files in the web viewer at ``http://127.0.0.1:<port>``; see the module."""
    paths = [str(Path(p).resolve()) for p in rrd_paths]
    if not paths:
        raise ViewerServeError("nothing to serve: no recording was given")
    grpc_port, page_port = free_port(), free_port()
    log_path = Path(tempfile.mkdtemp(prefix="skyvln-viewer-")) / "rerun.log"
    log_file = log_path.open("wb")
    command = [
        str(rerun_cli_path()),
        "--serve-web",
        "--bind",
        HOST,
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(page_port),
        "--server-memory-limit",
        memory_limit,
        *paths,
    ]
    # Its own session: a Ctrl-C in the terminal reaches the toolkit, which stops it cleanly.
    process = subprocess.Popen(
        command,
        start_new_session=True,
        preexec_fn=_terminated_with(os.getpid()) if sys.platform == "linux" else None,
        stdin=subprocess.DEVNULL,
        stdout=log_file,
        stderr=subprocess.STDOUT,
        env=rerun_environment(),
    )
    try:
        proxy = _start_proxy(process, port, page_port, grpc_port, log_path)
    except BaseException:
        # Never leave the executable running (it is in its own session: no Ctrl-C reaches it).
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
        log_file.close()
        shutil.rmtree(log_path.parent, ignore_errors=True)  # the error carries the log's tail
        raise
    thread = threading.Thread(target=proxy.serve_forever, name="viewer-proxy", daemon=True)
    thread.start()
    bound = int(proxy.server_address[1])
    grpc_url = f"rerun+http://{HOST}:{grpc_port}/proxy"
    url = f"http://{HOST}:{bound}/?url={quote(grpc_url, safe='')}"
    return ServedViewer(url, grpc_url, bound, process, proxy, log_path, log_file, thread)
