"""Stopping on a signal while the main thread is inside its own wait (glmav_observer/stop.py)."""

from __future__ import annotations

import subprocess
import sys

import pytest

# The main thread holds the stop event's lock, as it does at the start and the end of each
# of its own ``stop.wait()``, when SIGTERM arrives; Python runs the handler there, between
# two bytecodes. The event is then waited for from outside the lock.
_HOLDING_THE_LOCK = """
import os, signal, threading
{setup}
with stop._cond:  # CPython's Event: its Condition, whose lock is not re-entrant
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(10_000):  # the handler runs at one of these bytecodes
        pass
print("stopped", stop.wait(5.0))
"""

_HANDLER_SETS = """
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
"""

_STOP_ON_SIGNALS = """
from glmav_observer.app import stop_on_signals
stop = threading.Event()
inside = stop_on_signals(stop)  # serve's and replay's: its handlers until it is left
inside.__enter__()
"""

_HELPER = """
from glmav_observer.stop import set_from_signal_handler
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda signum, frame: set_from_signal_handler(stop))
"""


def _run(setup: str, timeout_s: float) -> str:
    code = _HOLDING_THE_LOCK.format(setup=setup)
    return subprocess.run(
        [sys.executable, "-c", code], check=True, capture_output=True, text=True, timeout=timeout_s
    ).stdout


def test_a_handler_that_sets_the_event_itself_hangs() -> None:
    # the reason for the module: Event.set() from the handler waits for its own thread
    # (2 s: the rest of the script takes milliseconds)
    with pytest.raises(subprocess.TimeoutExpired):
        _run(_HANDLER_SETS, 2.0)


@pytest.mark.parametrize("setup", [_HELPER, _STOP_ON_SIGNALS], ids=["helper", "serve"])
def test_the_service_stops_on_a_signal_inside_its_wait(setup: str) -> None:
    # 30 s: an interpreter's start and the service's imports on a loaded machine
    assert _run(setup, 30.0).strip() == "stopped True"
