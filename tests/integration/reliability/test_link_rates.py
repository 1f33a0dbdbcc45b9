"""Issue 29.6 live: the rates asked for fit the link (ingest/link_budget.py).

The vehicle (glmav_testkit.stream_vehicle, TCP on 127.0.0.1) streams through an emulated SiK
radio of 4,000 B/s (a 2 kB buffer, RADIO_STATUS at 1 Hz); or the link's capacity is set
in ``[rates]``. The service used to ask HIGHRES_IMU 250 Hz and ATTITUDE 100 Hz whatever
the link (29.5 kB/s of frames).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from glmav_observer.config import DEFAULT_MIN_RATES_HZ, parse_config
from glmav_observer.ingest.link_budget import cost_bytes_per_s
from glmav_testkit.rel_helpers import live_service, wait_until
from glmav_testkit.stream_vehicle import StreamVehicle

DEFAULTS_HZ = {"LOCAL_POSITION_NED": 4.0, "GPS_RAW_INT": 4.0, "EKF_STATUS_REPORT": 2.0}
SET_BY_SERVICE = ("ATTITUDE", "HIGHRES_IMU", "LOCAL_POSITION_NED")
#: the interval is sent in float32 µs, and the vehicle serves 1e6/interval: 1e-6 relative
REL = 1e-5


def _planned(vehicle: StreamVehicle) -> dict[str, float]:
    return {m: vehicle.rate_hz(m) for m in SET_BY_SERVICE}


@pytest.mark.timeout(90)
def test_rates_fit_a_radio_that_fills(free_tcp_port: Callable[[], int]) -> None:
    capacity = 4000.0
    port = free_tcp_port()
    vehicle = StreamVehicle(port, DEFAULTS_HZ, radio_bytes_per_s=capacity).start()
    try:
        with live_service(f"tcp:127.0.0.1:{port}", config=parse_config({})) as live:
            # asked at the configured rates first (the vehicle serves at most 50 Hz), the
            # radio fills, its RADIO_STATUS says so: asked again at rates that fit
            wait_until(lambda: vehicle.sets("HIGHRES_IMU"), 10.0, "first requests")
            wait_until(lambda: len(vehicle.sets("HIGHRES_IMU")) >= 2, 20.0, "re-planned")
            time.sleep(4.0)  # the radio drains: no further plan
            rates = _planned(vehicle)
            n_sets = {m: len(vehicle.sets(m)) for m in SET_BY_SERVICE}
            estimate = live.service._capacity[live.link.conn].radio_bytes_per_s
        # the estimate is the bytes received over one RADIO_STATUS period (1 s) while the
        # radio was full: its capacity, ± the jitter of the two statuses' arrival times
        # (the service's loop, sharing this process's GIL with the vehicle's: ±20 ms each)
        assert estimate is not None and abs(estimate - capacity) <= 0.05 * capacity, estimate
        # what the service set costs at most half of its estimate, shared with the 1 Hz
        # floors of the streams it does not need a rate of (SIM_STATE, EKF, GPS: 206 B/s)
        assert cost_bytes_per_s(rates) <= 0.5 * estimate, rates
        # the needs do not fit (4,556 B/s): all scaled by one factor, so their ratios stay
        need = DEFAULT_MIN_RATES_HZ
        assert rates["HIGHRES_IMU"] / rates["ATTITUDE"] == pytest.approx(
            need["HIGHRES_IMU"] / need["ATTITUDE"], rel=REL
        )
        assert rates["ATTITUDE"] / rates["LOCAL_POSITION_NED"] == pytest.approx(
            need["ATTITUDE"] / need["LOCAL_POSITION_NED"], rel=REL
        )
        assert rates["HIGHRES_IMU"] < 0.5 * 50.0  # half of the radio: under half the need
        # one re-plan, then stable: the radio has room again (no request in the last 4 s)
        assert vehicle.radio_dropped_frames > 0 and n_sets["HIGHRES_IMU"] == 2
    finally:
        vehicle.stop()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("link", ["serial", "tcp"])
def test_rates_fit_57600_baud(link: str, free_tcp_port: Callable[[], int]) -> None:
    """A serial link at 57,600 baud (a pseudo-terminal, opened as ``/dev/pts/N,57600``), or a
    TCP link with ``[rates] link_bytes_per_s = 5760`` (such a radio behind a network
    bridge): the rates of the 57,600-baud plan (link_budget's docstring)."""
    port = free_tcp_port()
    vehicle = StreamVehicle(port, DEFAULTS_HZ)
    if link == "serial":
        conn, cfg = f"{vehicle.start_pty()},57600", parse_config({})
    else:
        vehicle.start()
        conn = f"tcp:127.0.0.1:{port}"
        cfg = parse_config({"rates": {"link_bytes_per_s": 5760.0}})
    short = ("ATTITUDE", "HIGHRES_IMU")  # the streams below their plan
    try:
        with live_service(conn, config=cfg):
            wait_until(lambda: all(vehicle.sets(m) for m in short), 10.0, "requests")
            time.sleep(2.5)  # a full window more: nothing else asked
        # budget 2,880 B/s; the needs cost 4,556 B/s: each asked at 2880/4556 of its need
        scale = 2880.0 / 4556.0
        for m in short:
            asked_hz = 1e6 / vehicle.sets(m)[0].interval_us
            assert asked_hz == pytest.approx(DEFAULT_MIN_RATES_HZ[m] * scale, rel=REL), m
            assert len(vehicle.sets(m)) == 2  # the request, and its restore at the stop
        # LOCAL_POSITION_NED at the vehicle's 4 Hz is above its plan (3.2 Hz): not touched
        assert vehicle.sets("LOCAL_POSITION_NED") == []
    finally:
        vehicle.stop()
