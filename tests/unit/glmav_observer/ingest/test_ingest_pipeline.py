"""Ingest: SI conversion, vehicles by sysid, the cap, IMU preference, counters."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.ingest.convert import MG_TO_MPS2, RawImuScale
from glmav_observer.ingest.framing import FrameDecoder
from glmav_observer.ingest.pipeline import (
    Ingest,
    IngestConfig,
    NewVehicle,
    VehicleAutopilot,
    VehicleReset,
)
from glmav_observer.ingest.samples import AttitudeSample, ImuSample, ImuSource, VelocitySample


def _roundtrip(msg: Any, sysid: int = 1, compid: int = 1) -> Any:
    """Encode with the dialect and decode with our decoder (what a link does)."""
    mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    (out,) = FrameDecoder(datagram=True).feed(bytes(msg.pack(mav)))
    return out


def _att(t_ms: int, sysid: int = 1) -> Any:
    return _roundtrip(dialect.MAVLink_attitude_message(t_ms, 0.1, -0.2, 0.3, 1, 2, 3), sysid)


def test_units_of_each_message() -> None:
    ing = Ingest(IngestConfig(raw_imu_by_sysid={1: RawImuScale(0.01, 0.002)}))
    ev = ing.on_message(_att(1000), 0.0)
    assert isinstance(ev[0], NewVehicle)
    att = ev[1]
    assert isinstance(att, AttitudeSample)
    assert att.t_boot_s == 1.0
    assert att.euler_rad == pytest.approx((0.1, -0.2, 0.3))
    raw = dialect.MAVLink_raw_imu_message(1_004_000, 100, -50, -1000, 10, 20, 30, 0, 0, 0)
    (imu,) = ing.on_message(_roundtrip(raw), 0.0)
    assert isinstance(imu, ImuSample)
    assert imu.t_boot_s == 1.004
    assert imu.f_body_mps2 == pytest.approx((1.0, -0.5, -10.0))  # config scale 0.01
    assert imu.omega_body_radps == pytest.approx((0.02, 0.04, 0.06))
    sc = dialect.MAVLink_scaled_imu_message(1008, 0, 0, -1000, 0, 0, 100, 0, 0, 0)
    (imu2,) = ing.on_message(_roundtrip(sc), 0.0)
    assert isinstance(imu2, ImuSample)
    assert imu2.source is ImuSource.SCALED_IMU
    assert imu2.f_body_mps2[2] == pytest.approx(-1000 * MG_TO_MPS2)  # mG
    assert imu2.omega_body_radps[2] == pytest.approx(0.1)  # mrad/s
    lp = dialect.MAVLink_local_position_ned_message(1010, 1, 2, 3, 0.5, float("nan"), -0.5)
    (vel,) = ing.on_message(_roundtrip(lp), 0.0)
    assert isinstance(vel, VelocitySample)
    assert vel.v_ned_mps[0] == 0.5
    assert math.isnan(vel.v_ned_mps[1])  # a dropout is kept, as data


def test_best_imu_source_wins_and_falls_back() -> None:
    ing = Ingest(IngestConfig(imu_fallback_s=1.0))
    hr = dialect.MAVLink_highres_imu_message
    raw = dialect.MAVLink_raw_imu_message
    ing.on_message(_roundtrip(hr(1_000_000, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)), 0.0)
    assert ing.on_message(_roundtrip(raw(1_010_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0)), 0.0) == []
    assert ing.vehicles[1].counters["imu_superseded"] == 1
    # HIGHRES silent for > 1 s (the vehicle's clock goes on with ATTITUDE): RAW is used again
    for t_ms in (1500, 2000):
        att = dialect.MAVLink_attitude_message(t_ms, 0, 0, 0, 0, 0, 0)
        assert len(ing.on_message(_roundtrip(att), 0.0)) == 1
    (s,) = ing.on_message(_roundtrip(raw(2_100_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0)), 0.0)
    assert isinstance(s, ImuSample)
    assert s.source is ImuSource.RAW_IMU


def test_nan_attitude_counted_and_dropped() -> None:
    ing = Ingest(IngestConfig())
    m = _roundtrip(dialect.MAVLink_attitude_message(5, float("nan"), 0, 0, 0, 0, 0))
    ev = ing.on_message(m, 0.0)
    assert [type(e) for e in ev] == [NewVehicle]
    assert ing.vehicles[1].counters["nan_field"] == 1


def test_vehicle_cap_and_eviction() -> None:
    ing = Ingest(IngestConfig(max_vehicles=2, evict_idle_s=10.0))
    ing.on_message(_att(10, sysid=1), 0.0)
    ing.on_message(_att(10, sysid=2), 0.0)
    assert ing.on_message(_att(10, sysid=3), 1.0) == []
    assert ing.counters["vehicle_cap_dropped"] == 1
    ing.on_message(_att(20, sysid=2), 15.0)
    ev = ing.on_message(_att(10, sysid=3), 15.0)  # sysid 1 silent for 15 s: evicted
    assert sorted(ing.vehicles) == [2, 3]
    assert ing.counters["evicted"] == 1
    assert any(isinstance(e, NewVehicle) and e.sysid == 3 for e in ev)


def test_gcs_messages_do_not_create_vehicles() -> None:
    ing = Ingest(IngestConfig())
    hb = dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)
    assert ing.on_message(_roundtrip(hb, sysid=255, compid=190), 0.0) == []
    assert ing.vehicles == {}


def test_the_first_heartbeat_names_the_firmware_once() -> None:
    """A vehicle registered by its data (ATTITUDE) before its HEARTBEAT, and one by its
    HEARTBEAT: each is told its (autopilot, type) once, from its own component only."""
    ing = Ingest(IngestConfig())
    ing.on_message(_att(10, sysid=1), 0.0)
    copter = dialect.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)  # quad, ArduPilot
    other = _roundtrip(copter, sysid=1, compid=50)  # another component of sysid 1
    assert ing.on_message(other, 0.1) == []
    ev = ing.on_message(_roundtrip(copter), 0.2)
    assert ev == [VehicleAutopilot(1, 3, 2)]
    assert ing.on_message(_roundtrip(copter), 1.2) == []  # told once
    rover = dialect.MAVLink_heartbeat_message(10, 3, 0, 0, 4, 3)
    ev = ing.on_message(_roundtrip(rover, sysid=2), 0.3)
    assert ev == [NewVehicle(2, 1), VehicleAutopilot(2, 3, 10)]


def test_reboot_gives_vehicle_reset() -> None:
    ing = Ingest(IngestConfig())
    for t in range(100_000, 100_100, 10):
        ing.on_message(_att(t), 0.0)
    events = [e for t in range(10, 100, 10) for e in ing.on_message(_att(t), 0.0)]
    assert any(isinstance(e, VehicleReset) for e in events)
    assert ing.vehicles[1].counters["clock_reset"] == 1
