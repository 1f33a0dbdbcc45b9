"""Stopping on a signal without deadlocking.

Python runs a signal handler in the main thread between two bytecodes, which can be
inside that thread's own ``threading.Event.wait()`` while it holds the event's lock (at
the start and the end of every wait). ``Event.set()`` takes the same lock, which is not
re-entrant: called from the handler there, it waits for itself forever, and the process
hangs on SIGTERM until it is killed (the tail of its outputs lost). A handler therefore
hands the ``set()`` to a short-lived thread, which takes the lock once the main thread
lets go of it (within the wait it was in).
"""

from __future__ import annotations

import contextlib
import threading


def set_from_signal_handler(event: threading.Event) -> None:
    """Set ``event`` from a signal handler (see the module's docstring)."""
    # RuntimeError: the interpreter is shutting down, nothing left to stop
    with contextlib.suppress(RuntimeError):
        threading.Thread(target=event.set, name="stop-on-signal", daemon=True).start()
