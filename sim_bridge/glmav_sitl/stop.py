"""Stopping the simulator on SIGINT and SIGTERM.

The handler hands ``stop.set()`` to a short-lived thread. Called in the handler itself,
which Python runs in the main thread between two bytecodes, possibly inside that thread's
own ``stop.wait()`` with the event's (not re-entrant) lock held, it would wait for itself
forever and the simulator would hang until killed (glmav_observer/stop.py says the same of
the service).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from types import FrameType


def stop_on_signals(stop: threading.Event) -> None:
    """From now on SIGINT and SIGTERM set ``stop`` (call it from the main thread)."""

    def handler(signum: int, frame: FrameType | None) -> None:
        with contextlib.suppress(RuntimeError):  # the interpreter is shutting down
            threading.Thread(target=stop.set, name="stop-on-signal", daemon=True).start()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
