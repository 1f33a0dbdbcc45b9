"""Issue 29.5: ``serve`` stopped by SIGINT or SIGTERM sets the streams it changed back to
what they were (the interval the vehicle said before, MESSAGE_INTERVAL), on a live TCP link
to a vehicle (glmav_testkit.stream_vehicle). The service used to leave HIGHRES_IMU at 250 Hz
and ATTITUDE at 100 Hz on the vehicle after it exited."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Callable

import pytest

from glmav_testkit.rel_helpers import wait_until
from glmav_testkit.stream_vehicle import StreamVehicle

CLI = [sys.executable, "-m", "glmav_observer.cli"]
#: ArduPilot-like rates at boot (Hz); ATTITUDE at 4 Hz is below its 10 Hz need
DEFAULTS_HZ = {"ATTITUDE": 4.0, "LOCAL_POSITION_NED": 4.0, "GPS_RAW_INT": 4.0}


@pytest.mark.timeout(90)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_serve_restores_the_rates_on_a_clean_exit(
    sig: signal.Signals, free_tcp_port: Callable[[], int]
) -> None:
    port = free_tcp_port()
    vehicle = StreamVehicle(port, DEFAULTS_HZ).start()
    serve = subprocess.Popen(
        [*CLI, "serve", "--link", f"tcp:127.0.0.1:{port}", "--no-zenoh"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_until(
            lambda: vehicle.rate_hz("ATTITUDE") == 50.0 and vehicle.rate_hz("HIGHRES_IMU") == 50.0,
            30.0,
            "the service's rates in force (100 and 250 Hz asked, 50 Hz the vehicle's most)",
        )
        serve.send_signal(sig)
        _, err = serve.communicate(timeout=30)
        assert serve.returncode == 0, err[-2000:]
        # each stream set back once, to the interval the vehicle answered before: ATTITUDE
        # 250,000 µs (4 Hz); HIGHRES_IMU -1 (not sent): 0, the vehicle's default
        assert [c.interval_us for c in vehicle.sets("ATTITUDE")][1:] == [250_000.0]
        assert [c.interval_us for c in vehicle.sets("HIGHRES_IMU")][1:] == [0.0]
        assert vehicle.rate_hz("ATTITUDE") == 4.0 and vehicle.rate_hz("HIGHRES_IMU") == 0.0
        assert "stream rates restored" in err
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.communicate()
        vehicle.stop()


@pytest.mark.timeout(90)
def test_serve_workers_restore_the_rates_of_their_udp_vehicles(
    free_udp_port: Callable[[], int],
) -> None:
    """``serve --workers 2`` on a UDP port (routed by the kernel to the worker of the
    vehicle's system id, which answers from its own socket of the port): the worker sets
    the rates back when the parent stops it on SIGTERM."""
    svc_port, vehicle_port = free_udp_port(), free_udp_port()
    serve = subprocess.Popen(
        [*CLI, "serve", "--link", f"udpin:127.0.0.1:{svc_port}", "--no-zenoh", "--workers", "2"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    vehicle = StreamVehicle(vehicle_port, DEFAULTS_HZ).start_udp(svc_port)
    try:
        wait_until(
            lambda: vehicle.rate_hz("ATTITUDE") == 50.0 and vehicle.rate_hz("HIGHRES_IMU") == 50.0,
            30.0,
            "the service's rates in force",
        )
        serve.send_signal(signal.SIGTERM)
        _, err = serve.communicate(timeout=30)
        assert serve.returncode == 0, err[-2000:]
        assert [c.interval_us for c in vehicle.sets("ATTITUDE")][1:] == [250_000.0]
        assert [c.interval_us for c in vehicle.sets("HIGHRES_IMU")][1:] == [0.0]
        assert vehicle.rate_hz("ATTITUDE") == 4.0 and vehicle.rate_hz("HIGHRES_IMU") == 0.0
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.communicate()
        vehicle.stop()
