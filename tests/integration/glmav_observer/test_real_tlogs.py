"""Real ArduSub logs recorded by others (tests/data/real-tlogs): replay without a crash,
every rejected frame counted, estimates consistent with the vehicle's own velocity; the
log without a velocity measurement is refused by ``replay``, naming it."""

from __future__ import annotations

import bisect
import math
from pathlib import Path

import pytest

from glmav_observer.app_replay import replay_tlog
from glmav_observer.cli import main as cli_main
from glmav_observer.config import load_config
from glmav_observer.ingest.logfiles.tlog import check_tlog
from glmav_observer.records import MeasurementRecord, VelocityRecord
from glmav_testkit.sitl_live import MemorySink


def test_small_log_estimates_follow_the_vehicles_local_position_velocity(
    real_tlogs: Path,
) -> None:
    sink = MemorySink()
    s = replay_tlog(real_tlogs / "ardusub_small.tlog", load_config(None), [sink])
    link = next(iter(s.link_counters.values()))
    # pymavlink (robust_parsing) finds the same: 35,912 good frames, 4 bad CRCs
    assert link["frames_ok"] == 35_912
    assert link["bad_crc"] == 4
    v = s.vehicles[1]
    assert v.faults == []  # RAW_IMU at ~2 Hz: only dropout/freeze are tested, none occur
    # its GPS reports a 3D fix and a velocity of exactly 0 while the vehicle moves, and
    # loses the fix 8 times: never trusted (estimation/gps_bridge.py), no bridge starts
    assert v.counters.get("gps_bridge_starts", 0) == 0
    active = [r for r in sink.records if isinstance(r, VelocityRecord) and r.config == "active"]
    meas = [r for r in sink.records if isinstance(r, MeasurementRecord)]
    assert len(meas) == 792 and len(active) > 500
    times = [r.t_boot_s for r in active]
    sq = [0.0, 0.0, 0.0]
    n = 0
    for m in meas:
        i = bisect.bisect_right(times, m.t_boot_s) - 1
        if i < 0:
            continue
        n += 1
        for k in range(3):
            sq[k] += (active[i].v_ned_mps[k] - m.v_ned_mps[k]) ** 2
    rms = [math.sqrt(x / n) for x in sq]
    # the estimate at the last IMU step before each measurement (RAW_IMU ~2 Hz, so up to
    # 0.5 s older) against the vehicle's own EKF velocity (|v| <= 0.46 m/s in this log):
    # measured 0.03/0.05/0.11 m/s; bound 0.15 m/s = a third of the speed range
    assert max(rms) < 0.15, rms


def test_corrupt_log_replays_with_every_rejected_frame_counted(real_tlogs: Path) -> None:
    s = replay_tlog(real_tlogs / "ardusub_2023-04-18.tlog", load_config(None), [])
    link = next(iter(s.link_counters.values()))
    # README: about 1,967 frames pymavlink cannot parse; all counted, the rest used
    assert link["bad_crc"] == 1967
    assert link["frames_ok"] == 50_136
    assert s.messages == 50_136
    v = s.vehicles[1]
    # this disarmed vehicle sends no LOCAL_POSITION_NED: nothing to estimate, no crash,
    # its samples are counted (``replay`` refuses it: the next test)
    assert v.counters["rx_ATTITUDE"] == 6210
    assert v.counters["rx_RAW_IMU"] == 627
    assert s.records == 0


def test_replay_refuses_the_log_without_a_velocity_measurement_and_writes_nothing(
    real_tlogs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = real_tlogs / "ardusub_2023-04-18.tlog"
    out = tmp_path / "out.jsonl"
    assert cli_main(["replay", str(log), "--out", str(out), "--no-progress"]) == 2
    printed = capsys.readouterr()
    # ATTITUDE and RAW_IMU are there (counted above); GLOBAL_POSITION_INT is not taken
    assert printed.err == (
        f"glmav-observer replay: {log}: unsupported: this log has no velocity measurement "
        "(LOCAL_POSITION_NED)\n"
    )
    assert printed.out == "" and not out.exists()


def test_the_check_stops_early_and_the_replay_uses_its_frames_once(real_tlogs: Path) -> None:
    log = real_tlogs / "ardusub_small.tlog"
    scan = check_tlog(log)
    # QGroundControl's log: ATTITUDE, RAW_IMU and LOCAL_POSITION_NED within its first
    # 3,582 of 1,510,263 bytes: the check decodes 0.2 % of the log
    assert scan.complete_vehicle == 1 and scan.scanned_bytes == 3582
    a, b = MemorySink(), MemorySink()
    with_scan = replay_tlog(log, load_config(None), [a], scan=scan)
    without = replay_tlog(log, load_config(None), [b])
    # the frames the check decoded are replayed once: the same counts, the same records
    assert with_scan.link_counters == without.link_counters
    assert next(iter(with_scan.link_counters.values()))["frames_ok"] == 35_912
    assert with_scan.messages == without.messages == 35_912
    assert len(a.records) > 1000
    assert [r.to_dict() for r in a.records] == [r.to_dict() for r in b.records]
