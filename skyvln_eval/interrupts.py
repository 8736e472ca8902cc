"""Stopping a long command from outside: SIGTERM is taken as Ctrl-C.

Python's own SIGTERM action ends the process at once, so nothing a command holds is let
go: worker processes, a viewer's server, temporary files. Inside
:func:`terminate_like_ctrl_c` SIGTERM raises ``KeyboardInterrupt`` instead, and the
command stops as it does on Ctrl-C.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


@contextmanager
def terminate_like_ctrl_c() -> Iterator[None]:
    """SIGTERM raises ``KeyboardInterrupt`` in the main thread until the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may set a handler; a caller's thread keeps its own
        return
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
