"""A telemetry log is checked for what the estimator needs before it is replayed: the
vehicle's attitude, IMU and velocity measurement, named when missing; the scan stops at
the frame that completes them, and the replay goes on from there with every frame once."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from glmav_observer.ingest.framing import FrameCounters, iter_tlog
from glmav_observer.ingest.logfiles import LogError, UnsupportedLogError
from glmav_observer.ingest.logfiles import tlog as tlog_mod
from glmav_observer.ingest.logfiles.tlog import check_tlog, scan_tlog


def _frame(msg: object, sysid: int) -> bytes:
    mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return bytes(msg.pack(mav))  # type: ignore[attr-defined]


def _msg(kind: str, t_ms: int) -> object:
    if kind == "att":
        return dialect.MAVLink_attitude_message(t_ms, 0.1, -0.2, 0.3, 0.01, 0.02, 0.03)
    if kind == "imu":
        return dialect.MAVLink_raw_imu_message(t_ms * 1000, 0, 0, -1000, 1, 2, 3, 0, 0, 0)
    if kind == "lpn":
        return dialect.MAVLink_local_position_ned_message(t_ms, 1.0, 2.0, -3.0, 0.5, 0.2, 0.0)
    if kind == "gpi":  # a velocity too, but not the measurement the service takes
        return dialect.MAVLink_global_position_int_message(t_ms, 0, 0, 0, 0, 50, 20, 0, 0)
    return dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)  # a GCS


def _tlog(*frames: tuple[str, int]) -> bytes:
    """A tlog of (message kind, system id) frames, 10 ms apart."""
    out = b""
    for k, (kind, sysid) in enumerate(frames):
        out += struct.pack(">Q", 1_700_000_000_000_000 + 10_000 * k)
        out += _frame(_msg(kind, 10 * k), sysid)
    return out


def _write(tmp_path: Path, data: bytes) -> Path:
    p = tmp_path / "x.tlog"
    p.write_bytes(data)
    return p


def test_a_vehicle_with_attitude_imu_and_velocity_passes_and_the_scan_stops_there() -> None:
    frames = [("hb", 255), ("att", 1), ("imu", 1), ("att", 1), ("lpn", 1)] + [("att", 1)] * 50
    data = _tlog(*frames)
    scan = scan_tlog(data)
    assert scan.missing() == "" and scan.complete_vehicle == 1
    # stopped at the fifth frame (the first LOCAL_POSITION_NED), 50 frames unread
    assert scan.frames_ok == 5
    assert scan.scanned_bytes == len(_tlog(*frames[:4]))


def test_the_missing_velocity_measurement_is_named() -> None:
    scan = scan_tlog(_tlog(*[("hb", 255), ("att", 1), ("imu", 1), ("gpi", 1)] * 20))
    assert scan.complete_vehicle is None
    assert scan.missing() == "velocity measurement (LOCAL_POSITION_NED)"
    assert scan.frames_ok == 80 and scan.scanned_bytes == scan.size_bytes  # read to the end


def test_a_log_of_a_ground_station_alone_lacks_everything() -> None:
    scan = scan_tlog(_tlog(*[("hb", 255)] * 5))
    assert scan.missing() == (
        "attitude (ATTITUDE), no IMU data (HIGHRES_IMU, SCALED_IMU or RAW_IMU), "
        "no velocity measurement (LOCAL_POSITION_NED)"
    )


def test_needs_are_met_per_vehicle_not_across_vehicles() -> None:
    # vehicle 1 sends attitude and IMU, vehicle 2 only the velocity: neither can be estimated
    split = _tlog(("att", 1), ("imu", 1), ("lpn", 2), ("att", 1))
    assert scan_tlog(split).missing() == "velocity measurement (LOCAL_POSITION_NED) from vehicle 1"
    # a second vehicle with everything: the log replays (estimating that one)
    assert scan_tlog(split + _tlog(("att", 3), ("imu", 3), ("lpn", 3))).complete_vehicle == 3


def test_check_refuses_with_the_reason_and_names_an_unreadable_file(tmp_path: Path) -> None:
    path = _write(tmp_path, _tlog(("att", 1), ("lpn", 1)))
    with pytest.raises(UnsupportedLogError) as err:
        check_tlog(path)
    assert str(err.value) == (
        f"{path}: unsupported: this log has no IMU data (HIGHRES_IMU, SCALED_IMU or RAW_IMU)"
    )
    empty = _write(tmp_path, b"")
    with pytest.raises(LogError, match=r"nothing could be read as MAVLink \(0 bytes, 0 frames"):
        check_tlog(empty)


def _replayed(
    data: bytes, max_prefix: int | None, monkeypatch: pytest.MonkeyPatch
) -> dict[str, int]:
    """The scan's replay records are the log's frames, each once, with the same counters."""
    if max_prefix is not None:
        monkeypatch.setattr(tlog_mod, "MAX_PREFIX_RECORDS", max_prefix)
    plain_counters = FrameCounters()
    plain = [(r.offset, r.t_host_us, r.msg.get_type()) for r in iter_tlog(data, plain_counters)]
    scan = scan_tlog(data)
    assert scan.missing() == ""
    records, counters = scan.replay_records()
    assert [(r.offset, r.t_host_us, r.msg.get_type()) for r in records] == plain
    assert counters.as_dict() == plain_counters.as_dict()
    return counters.as_dict()


@pytest.mark.parametrize("max_prefix", [None, 2], ids=["prefix-kept", "prefix-dropped"])
def test_the_replay_goes_on_from_the_scan_with_every_frame_once(
    max_prefix: int | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    good = _tlog(("hb", 255), ("att", 1), ("imu", 1), ("lpn", 1), ("att", 1), ("imu", 1))
    # a damaged frame before and after the scan's stop: counted once each
    bad = bytearray(good)
    bad[len(_tlog(("hb", 255))) + 12] ^= 0xFF  # in the first ATTITUDE's payload: bad CRC
    data = bytes(bad) + good
    counted = _replayed(data, max_prefix, monkeypatch)
    assert counted["bad_crc"] == 1 and counted["frames_ok"] == 11
