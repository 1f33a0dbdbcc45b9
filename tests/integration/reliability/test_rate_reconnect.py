"""Issue 29.5 live: rate requests over a TCP link that drops and a vehicle that reboots.

The vehicle (glmav_testkit.stream_vehicle) serves TCP on 127.0.0.1 like ArduPilot's SITL and
boots with ArduPilot-like default rates: LOCAL_POSITION_NED and GPS_RAW_INT at 4 Hz,
EKF_STATUS_REPORT at 2 Hz, no ATTITUDE, no IMU. The service asks for the rest. Then the
link goes down for 6 s (the service used to count requests while it was down and grow
their back-off), comes back from a rebooted vehicle (the service used to ask again only
after its back-off: 17 s and 53 s after ArduPilot's reboot), the vehicle reboots again on
the same link (time_boot going back), and the service stops (the rates set back).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from glmav_observer.config import parse_config
from glmav_testkit.rel_helpers import live_service, wait_until
from glmav_testkit.stream_vehicle import StreamVehicle

#: ArduPilot-like rates at boot (Hz)
DEFAULTS_HZ = {"LOCAL_POSITION_NED": 4.0, "GPS_RAW_INT": 4.0, "EKF_STATUS_REPORT": 2.0}
#: what the service sets on this vehicle with its default [rates]: the streams below their
#: need (ATTITUDE 0 < 10 Hz, HIGHRES_IMU 0 < 50 Hz, LOCAL_POSITION_NED 4 < 0.9 x 5 Hz);
#: SIM_STATE too (absent: asked once; this vehicle does not have it)
SET_BY_SERVICE = ("ATTITUDE", "HIGHRES_IMU", "LOCAL_POSITION_NED")
#: the issue's bound: streams asked again within 2 s of the vehicle's reboot (vehicle time)
RENEW_WITHIN_S = 2.0


@pytest.mark.timeout(120)
def test_requests_count_when_sent_and_are_renewed_after_reconnect_and_reboot(
    free_tcp_port: Callable[[], int],
) -> None:
    port = free_tcp_port()
    vehicle = StreamVehicle(port, DEFAULTS_HZ).start()
    try:
        with live_service(f"tcp:127.0.0.1:{port}", config=parse_config({})) as live:
            svc = live.service
            # boot 1: asked after the 2 s window (+ the 1 s check period)
            wait_until(lambda: all(vehicle.sets(m) for m in SET_BY_SERVICE), 10.0, "requests")
            wait_until(lambda: vehicle.rate_hz("ATTITUDE") > 0, 5.0, "ATTITUDE set")
            for m in SET_BY_SERVICE:
                # each stream's interval asked first (what is restored at the stop), once
                assert (
                    len(vehicle.gets(m)) == 1
                    and vehicle.gets(m)[0].t_boot_s <= vehicle.sets(m)[0].t_boot_s
                )
            time.sleep(1.5)  # a few checks with the streams at their rates: nothing more sent
            rates = svc.ingest.vehicles[1].rates
            sent_before = svc.counters["rate_requests_sent"]
            asked_before = {m: rates.asked(m) for m in SET_BY_SERVICE}
            assert asked_before == dict.fromkeys(SET_BY_SERVICE, 1)

            # the link goes down for 6 s: the streams go silent (short) for 4 s of checks
            vehicle.drop()
            wait_until(lambda: live.link.down, 5.0, "link down")
            time.sleep(6.0)
            assert live.link.down  # refused: nobody listens
            assert svc.counters["rate_requests_sent"] == sent_before
            assert {m: rates.asked(m) for m in SET_BY_SERVICE} == asked_before

            # back, from a rebooted vehicle: every stream the service had set is asked again
            # at once (its back-off from the start), once, though the clock reset follows
            vehicle.reboot()
            vehicle.listen()
            wait_until(lambda: len(vehicle.accepted) == 2, 10.0, "reconnect (backoff <= 5 s)")
            wait_until(lambda: all(vehicle.sets(m, boot=2) for m in SET_BY_SERVICE), 5.0, "renewed")
            _, t_accept_s = vehicle.accepted[1]
            for m in SET_BY_SERVICE:
                t_set = vehicle.sets(m, boot=2)[0].t_boot_s
                assert t_set - t_accept_s <= RENEW_WITHIN_S, (m, t_set, t_accept_s)
            time.sleep(2.5)  # the clock reset is seen (5 samples): no second request
            for m in SET_BY_SERVICE:
                assert len(vehicle.sets(m, boot=2)) == 1, vehicle.sets(m, boot=2)
                assert rates.asked(m) == 2
            assert svc.summary().vehicles[1].counters.get("clock_reset", 0) == 1

            # a reboot on the same link: time_boot goes back; five samples of the 4 Hz
            # LOCAL_POSITION_NED confirm the new timeline (1.0 s: the vehicle's only timed
            # stream at boot; GPS_RAW_INT is untimed); ATTITUDE, off at boot, would be judged
            # short only after 2 s of silence and asked at the next check
            vehicle.reboot()
            wait_until(lambda: all(vehicle.sets(m, boot=3) for m in SET_BY_SERVICE), 5.0, "reboot")
            for m in SET_BY_SERVICE:
                t_set = vehicle.sets(m, boot=3)[0].t_boot_s
                assert t_set <= RENEW_WITHIN_S, (m, t_set)
            wait_until(lambda: vehicle.t_boot_s() > 3.0, 5.0, "3 s of the new boot")
            for m in SET_BY_SERVICE:
                assert len(vehicle.sets(m, boot=3)) == 1 and rates.asked(m) == 3
            assert svc.summary().vehicles[1].counters.get("clock_reset", 0) == 2
            assert vehicle.rate_hz("ATTITUDE") == 50.0  # 100 Hz asked, the vehicle's most
            n_before_stop = {m: len(vehicle.sets(m)) for m in SET_BY_SERVICE}
        # stopped: every stream the service set is back at its rate before (the interval
        # MESSAGE_INTERVAL said; for a stream it did not send, -1: interval 0, the default)
        for m in SET_BY_SERVICE:
            last = vehicle.sets(m)[-1]
            assert len(vehicle.sets(m)) == n_before_stop[m] + 1
            before_us = 1e6 / DEFAULTS_HZ[m] if m in DEFAULTS_HZ else 0.0
            assert last.interval_us == pytest.approx(before_us, abs=1.0), last  # float32 µs
            assert vehicle.rate_hz(m) == DEFAULTS_HZ.get(m, 0.0)
        assert svc.counters["rate_restores_sent"] == len(SET_BY_SERVICE) + 1  # + SIM_STATE
    finally:
        vehicle.stop()
