"""The simulator stops on a signal while its main thread is inside its own wait
(glmav_sitl/stop.py; the reason is shown in tests/unit/glmav_observer/test_stop.py)."""

from __future__ import annotations

import subprocess
import sys

_CODE = """
import os, signal, threading
from glmav_sitl.stop import stop_on_signals
stop = threading.Event()
stop_on_signals(stop)  # glmav-sitl run's and fleet's
with stop._cond:  # as at the start and the end of the run loop's stop.wait(lag)
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(10_000):  # the handler runs at one of these bytecodes
        pass
print("stopped", stop.wait(5.0))
"""


def test_the_simulator_stops_on_a_signal_inside_its_wait() -> None:
    # 30 s: an interpreter's start on a loaded machine (the script itself takes milliseconds)
    out = subprocess.run(
        [sys.executable, "-c", _CODE], check=True, capture_output=True, text=True, timeout=30.0
    ).stdout
    assert out.strip() == "stopped True"
