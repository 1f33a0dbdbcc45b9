"""MAVSDK (the native v4 binding, bundling the C++ core) as a real client of the simulator."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import pytest

from glmav_sitl.scenario import Setpoint, load_scenario
from glmav_sitl.simulator import TruthState
from glmav_testkit.sitl_helpers import background_run


@pytest.mark.timeout(90)
def test_mavsdk_discovers_vehicle_and_telemetry_matches_truth(
    free_udp_port: Callable[[], int],
) -> None:
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.telemetry import Telemetry

    port = free_udp_port()
    # a climbing turn so that attitude, velocity and specific force are all non-trivial;
    # bias off so that "within the noise" is a clean bound (bias is tested elsewhere)
    sc = replace(
        load_scenario("climbing-turn"),
        sensors={"noise": True, "bias": False, "noise_scale": 1.0, "bias_scale": 1.0},
        setpoints=(Setpoint(0.0, "turn", speed_mps=3.0, turn_rate_radps=0.3, climb_rate_mps=1.0),),
    )
    truth: dict[int, TruthState] = {}
    lock = threading.Lock()

    def on_truth(t: TruthState) -> None:
        with lock:
            truth[round(t.t_s * 1e6)] = t

    att: list[Any] = []
    imu: list[Any] = []
    pv: list[tuple[float, Any]] = []
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        with background_run(
            scenario=sc,
            links=[f"udpout:127.0.0.1:{port}"],
            duration_s=120.0,
            speed="realtime",
            on_truth=on_truth,
            truth_every_s=0.001,
        ):
            system = drone.first_autopilot(timeout_s=10.0)
            assert system is not None, "MAVSDK did not discover the vehicle"
            assert system.get_system_id() == 1
            tel = Telemetry(system)
            tel.subscribe_attitude_euler(lambda m, _: att.append(m))
            tel.subscribe_imu(lambda m, _: imu.append(m))
            tel.subscribe_position_velocity_ned(lambda m, _: pv.append((time.monotonic(), m)))
            deadline = time.monotonic() + 20.0
            # fly into the turn (starts at 3 s) and collect a few seconds of telemetry
            while time.monotonic() < deadline and (len(pv) < 120 or len(imu) < 500):
                time.sleep(0.05)  # MAVSDK delivers on its own thread; nothing to await here
            tel.destroy()
    finally:
        drone.destroy()
    assert len(att) >= 200 and len(imu) >= 500 and len(pv) >= 120
    with lock:
        snap = dict(truth)

    def at(t_us: int) -> TruthState:
        return snap[round(t_us / 1000) * 1000]  # truth every 1 ms; timestamps are ms multiples

    # ATTITUDE: sigma 0.005 rad per angle -> 5 sigma = 0.025 rad = 1.43 deg
    n_att = 0
    for m in att:
        if m.timestamp_us == 0 or round(m.timestamp_us / 1000) * 1000 not in snap:
            continue
        tr = at(m.timestamp_us)
        for got_deg, true_rad in zip(
            (m.roll_deg, m.pitch_deg, m.yaw_deg), tr.euler_rad, strict=True
        ):
            err = (math.radians(got_deg) - true_rad + math.pi) % (2 * math.pi) - math.pi
            assert abs(err) < 0.025
        n_att += 1
    assert n_att >= 100
    # IMU (HIGHRES_IMU): accel sigma 4e-3*sqrt(250) = 0.063 m/s^2, gyro 5.4e-3 rad/s; 5 sigma
    n_imu = 0
    for m in imu:
        key = round(m.timestamp_us / 1000) * 1000
        if m.timestamp_us == 0 or key not in snap:
            continue
        tr = snap[key]
        a = m.acceleration_frd
        w = m.angular_velocity_frd
        for got, true in zip(
            (a.forward_m_s2, a.right_m_s2, a.down_m_s2), tr.f_body_mps2, strict=True
        ):
            assert abs(got - true) < 5 * 0.063
        for got, true in zip(
            (w.forward_rad_s, w.right_rad_s, w.down_rad_s), tr.omega_body_radps, strict=True
        ):
            assert abs(got - true) < 5 * 5.4e-3
        n_imu += 1
    assert n_imu >= 100
    # LOCAL_POSITION_NED via MAVSDK has no timestamp: compare with the latest truth and allow
    # the loopback latency (< 0.1 s) times the speed change (accel < 1 m/s^2) on top of 5 sigma
    latest = max(snap)
    _last_t, last_pv = pv[-1]
    tr = snap[latest]
    v = last_pv.velocity
    for got, true in zip((v.north_m_s, v.east_m_s, v.down_m_s), tr.v_ned_mps, strict=True):
        assert abs(got - true) < 5 * 0.05 + 0.1
    p = last_pv.position
    for got, true in zip((p.north_m, p.east_m, p.down_m), tr.p_ned_m, strict=True):
        assert abs(got - true) < 5 * 0.3 + 0.4  # 0.1 s at up to 3.2 m/s
    # the vehicle was really turning and climbing (the comparison is not against zeros)
    assert math.hypot(v.north_m_s, v.east_m_s) > 2.0 and -v.down_m_s > 0.5
