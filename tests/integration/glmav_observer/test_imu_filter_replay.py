"""Where the accelerometer filter's delay comes from on a replay (estimation/imu_filter.py):
an ArduPilot tlog's HEARTBEAT (the firmware's default, 20 Hz), an ArduPilot dataflash
log's own INS_ACCEL_FILTER parameter, nothing for a PX4 log."""

from __future__ import annotations

import gzip
import lzma
from pathlib import Path

from glmav_observer.app_replay import replay_flight_log, replay_tlog
from glmav_observer.config import ServiceConfig

DATA = Path(__file__).resolve().parents[2] / "data"
#: √2/(2π·20 Hz) in µs, rounded as the counter is
DELAY_20HZ_US = 11254


def test_a_tlog_takes_the_firmware_default_from_its_heartbeat(tmp_path: Path) -> None:
    log = tmp_path / "a.tlog"
    log.write_bytes(lzma.decompress((DATA / "ardupilot_sitl" / "a_quad_wind.tlog.xz").read_bytes()))
    summary = replay_tlog(log, ServiceConfig(request_rates=False), [])
    (vehicle,) = summary.vehicles.values()
    assert vehicle.counters["imu_filter_delay_us"] == DELAY_20HZ_US


def test_a_dataflash_log_takes_its_own_parameter_and_px4_none(tmp_path: Path) -> None:
    bin_path = tmp_path / "ac.BIN"
    bin_path.write_bytes(
        gzip.decompress((DATA / "public-logs" / "arducopter_sitl_trimmed.BIN.gz").read_bytes())
    )
    ulg = tmp_path / "px4.ulg"
    ulg.write_bytes(
        gzip.decompress((DATA / "public-logs" / "px4_sitl_trimmed.ulg.gz").read_bytes())
    )
    ardupilot = replay_flight_log(bin_path, ServiceConfig(), velocity_source="ekf")
    # its INS_ACCEL_FILTER is 20 Hz (the log's PARM): the same delay, from the parameter
    assert ardupilot.vehicle_summary is not None
    assert ardupilot.vehicle_summary.counters["imu_filter_delay_us"] == DELAY_20HZ_US
    px4 = replay_flight_log(ulg, ServiceConfig(), velocity_source="ekf")
    assert px4.vehicle_summary is not None
    assert px4.vehicle_summary.counters.get("imu_filter_delay_us", 0) == 0
