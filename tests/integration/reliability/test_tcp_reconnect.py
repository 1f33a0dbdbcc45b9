"""TCP link dropped and restored: the service reconnects (with backoff) and goes on.

The vehicle side (the simulator as a TCP server, ``tcpin:``) goes away and comes back on
the same port as a rebooted vehicle; the service's ``tcp:`` link (``ingest/links.py``)
must count the disconnect, reconnect, and estimate the new boot from zero.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from glmav_sitl.runner import run
from glmav_testkit.rel_helpers import live_service, wait_until


@pytest.mark.timeout(60)
def test_tcp_link_dropped_and_restored_estimation_resumes(
    free_tcp_port: Callable[[], int],
) -> None:
    port = free_tcp_port()
    server = f"tcpin:127.0.0.1:{port}"
    stop1 = threading.Event()
    started = threading.Event()
    t1 = threading.Thread(
        target=run,
        args=("hover", [server]),
        kwargs={"duration_s": 20.0, "speed": 1.0, "stop_event": stop1, "started": started},
        daemon=True,
    )
    t1.start()
    wait_until(started.is_set, 10.0, "vehicle listening")
    with live_service(f"tcp:127.0.0.1:{port}") as live:
        wait_until(lambda: len(live.velocity()) > 100, 10.0, "estimates over TCP")
        stop1.set()  # the vehicle side goes away: its sockets close
        t1.join(10.0)
        n_before = len(live.velocity())
        t2 = threading.Thread(
            target=run,
            args=("hover", [server]),
            kwargs={"duration_s": 8.0, "speed": 1.0},
            daemon=True,
        )
        t2.start()  # back on the same port (a rebooted vehicle: its clock restarts)
        wait_until(lambda: len(live.velocity()) > n_before + 100, 10.0, "estimates after reconnect")
        t2.join(15.0)
        assert live.link.counters["tcp_disconnects"] >= 1
        assert live.link.counters["tcp_reconnects"] >= 1
        # the new flight's clock starts at zero again: one reset, no mixing of boots
        assert live.service.summary().vehicles[1].counters.get("clock_reset", 0) == 1
