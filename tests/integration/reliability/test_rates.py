"""Issue 14.3 live: a vehicle that streams nothing is registered on its HEARTBEAT and
asked; measured rates agree with MAVSDK's; a rate a ground station set above what the
estimator needs is left alone."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import pytest

from glmav_observer.config import parse_config
from glmav_sitl.scenario import load_sitl_config
from glmav_testkit.rel_helpers import live_service, sitl_thread, wait_until


@pytest.mark.timeout(90)
def test_a_silent_vehicle_is_asked_for_its_streams(free_udp_port: Callable[[], int]) -> None:
    """ArduPilot's defaults: every stream rate 0, HEARTBEAT only. The service used to
    wait for a first sample forever (0 requests, 0 records)."""
    port = free_udp_port()
    silent = {k: 0.0 for k in ("raw_imu", "scaled_imu", "highres_imu", "attitude")}
    silent.update(local_position_ned=0.0, sim_state=0.0)
    sitl = dataclasses.replace(load_sitl_config(), rates_hz=silent)
    with (
        live_service(f"udpin:127.0.0.1:{port}", config=parse_config({})) as live,
        sitl_thread(
            "hover", [f"udpout:127.0.0.1:{port}"], duration_s=6.0, speed=1.0, seed=1, sitl=sitl
        ) as (_, out),
    ):
        pass
    # the configured six (ATTITUDE, HIGHRES_IMU, LOCAL_POSITION_NED, SIM_STATE, and what the
    # autopilot's velocity rests on: EKF_STATUS_REPORT, GPS_RAW_INT), once, each after a
    # query of its interval before (GET_MESSAGE_INTERVAL: what is restored at the stop): 12
    # (the service's restores come after the vehicle stopped)
    assert out[0].commands_received == 12
    sent = out[0].messages_sent
    # asked after the 2 s window (+ the 1 s check period): >= 2 s of 250 Hz IMU follow
    assert sent["highres_imu"] > 500 and sent["attitude"] > 200, sent
    assert live.service.records > 1000
    v = live.service.summary().vehicles[1]
    assert v.counters["heartbeat"] >= 5 and v.counters["rx_HIGHRES_IMU"] > 500


@pytest.mark.timeout(120)
def test_rates_agree_with_mavsdk_and_its_own_setting_is_respected(
    free_udp_port: Callable[[], int],
) -> None:
    """The simulator streams to the service and to MAVSDK. Every live run used to publish
    ATTITUDE 0.0, HIGHRES_IMU 1e9; MAVSDK's set_rate_attitude_euler(10) was overridden
    within 4 s (re-requests every 5 s). Rates are compared over the same seconds."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.telemetry import Telemetry

    svc_port, gcs_port = free_udp_port(), free_udp_port()
    att_us: list[int] = []
    imu_us: list[int] = []
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{gcs_port}")
        with (
            live_service(f"udpin:127.0.0.1:{svc_port}", config=parse_config({})) as live,
            sitl_thread(
                "hover",
                [f"udpout:127.0.0.1:{svc_port}", f"udpout:127.0.0.1:{gcs_port}"],
                duration_s=20.0,
                speed=1.0,
                seed=1,
            ) as (stop, _),
        ):
            system = drone.first_autopilot(timeout_s=10.0)
            assert system is not None
            tel = Telemetry(system)
            tel.subscribe_attitude_euler(lambda m, _: att_us.append(int(m.timestamp_us)))
            tel.subscribe_imu(lambda m, _: imu_us.append(int(m.timestamp_us)))
            wait_until(lambda: len(imu_us) > 1000, 20.0, "4 s of MAVSDK IMU")

            def ours() -> dict[str, float]:
                return live.service.ingest.vehicles[1].rates.rates()

            def theirs(ts: list[int]) -> float:
                last = ts[-1]
                recent = [t for t in ts if t > last - 2_000_000]  # the same 2 s window
                return (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-6)

            got = ours()
            mav_att, mav_imu = theirs(list(att_us)), theirs(list(imu_us))
            # both count the same stamps over ~2 s (200 and 500 samples): ±1 sample at
            # either end of a window that may be offset by a few ms -> 2 % margin
            assert abs(got["ATTITUDE"] - mav_att) <= 0.02 * mav_att, (got, mav_att)
            assert abs(got["HIGHRES_IMU"] - mav_imu) <= 0.02 * mav_imu, (got, mav_imu)
            assert abs(mav_att - 100.0) < 3.0 and abs(mav_imu - 250.0) < 7.5
            # the GCS slows ATTITUDE to 10 Hz: still what the estimator needs (10 Hz)
            tel.set_rate_attitude_euler(10.0)
            t_set = time.monotonic()
            wait_until(lambda: 9.0 < ours().get("ATTITUDE", 0.0) < 11.0, 15.0, "10 Hz seen")
            time.sleep(max(0.0, 8.0 - (time.monotonic() - t_set)))  # > 1 retry_s + window
            assert 9.0 < ours()["ATTITUDE"] < 11.0  # not overridden back to 100 Hz
            tel.destroy()
            stop.set()
        counters: dict[str, Any] = live.service.summary().service_counters
        # ATTITUDE was never short, so never asked; the two streams glmav-sitl does not send
        # (EKF_STATUS_REPORT, GPS_RAW_INT: the autopilot's aiding) were asked once each
        rates = live.service.ingest.vehicles[1].rates
        assert rates.asked("ATTITUDE") == 0 and rates.asked("HIGHRES_IMU") == 0
        assert counters.get("rate_requests_sent", 0) == 2
    finally:
        drone.destroy()
