"""batch's duration and input rates of a MAVLink .tlog (the report showed "None s" and
"- / - / -" for them): from the vehicle's record times and its receive counters."""

from __future__ import annotations

import pytest

from glmav_observer.app_summary import VehicleSummary
from glmav_observer.commands.batch_log import _tlog_duration_and_rates
from glmav_observer.records import MeasurementRecord


def _vehicle(sysid: int, counters: dict[str, int]) -> VehicleSummary:
    return VehicleSummary(sysid, {}, {}, 0, [], [], counters, "full")


def test_duration_and_rates_from_record_times_and_counters() -> None:
    # vehicle 1's records span 10.0 s -> 30.0 s; vehicle 2's (another sysid) are ignored
    records = [
        MeasurementRecord(1, t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), i)
        for i, t in enumerate((10.0, 15.0, 30.0))
    ] + [MeasurementRecord(2, 500.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0)]
    counters = {
        "rx_ATTITUDE": 1000,  # 50 Hz over 20 s
        "rx_RAW_IMU": 1000,
        "rx_SCALED_IMU": 40,  # a fallback IMU seen briefly: the busiest IMU counts
        "rx_LOCAL_POSITION_NED": 200,
        "rx_SIM_STATE": 999,
        "heartbeat": 20,
    }
    got = _tlog_duration_and_rates(records, _vehicle(1, counters))
    assert got["duration_s"] == pytest.approx(20.0)
    assert got["rate_attitude_hz"] == 50.0
    assert got["rate_imu_hz"] == 50.0
    assert got["rate_ekf_hz"] == 10.0  # LOCAL_POSITION_NED: the autopilot's EKF output
    assert got["rate_truth_hz"] == 49.95
    assert "rate_gps_hz" not in got  # no GPS_RAW_INT received: the report shows "-"


def test_no_vehicle_or_no_time_span_gives_no_rates() -> None:
    assert _tlog_duration_and_rates([], None) == {"duration_s": None}
    one = [MeasurementRecord(1, 3.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0)]
    assert _tlog_duration_and_rates(one, _vehicle(1, {"rx_ATTITUDE": 5})) == {"duration_s": 0.0}
