"""The compatibility matrix (tests/data/public-logs/matrix.toml, docs/logs.md): every public
log replays, or is refused with "unsupported: this log has no X" (exit 2), never called
damaged; where the log has an EKF and a GPS of 5 Hz or more, ``full`` against the log's
EKF in flight is within 0.3/0.3/0.5 m/s RMSE (north/east/down) and nothing is isolated on
a flight whose EKF rejected no GPS velocity (issue 33's bounds), unless the matrix records
why that log exceeds them (then the test checks it still does, so that a fix is noticed).
"""

from __future__ import annotations

import lzma
import tomllib
from pathlib import Path
from typing import Any

import pytest

from glmav_observer.app_replay import LogReplaySummary, replay_flight_log, replay_tlog
from glmav_observer.cli import main as cli_main
from glmav_observer.config import load_config
from glmav_observer.ingest.logfiles import UnsupportedLogError, detect_format
from glmav_observer.ingest.logfiles.tlog import check_tlog
from glmav_observer.records import Record, VelocityRecord

DATA = Path(__file__).resolve().parents[2] / "data" / "public-logs"
ENTRIES: list[dict[str, Any]] = tomllib.loads((DATA / "matrix.toml").read_text())["log"]
#: issue 33's bounds: RMSE (m/s) north, east, down of ``full`` against the EKF in flight
RMSE_BOUND_NED_MPS = (0.3, 0.3, 0.5)
#: a "5 Hz" GPS by its median interval; 1 % for the receivers' clock jitter
MIN_GPS_RATE_HZ = 5.0 * 0.99


@pytest.fixture(scope="module")
def matrix_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every matrix log, decompressed into one folder."""
    out = tmp_path_factory.mktemp("matrix")
    for e in ENTRIES:
        data = lzma.decompress((DATA / "matrix" / f"{e['file']}.xz").read_bytes())
        (out / e["file"]).write_bytes(data)
    return out


class _Records:
    """A sink counting the velocity estimates."""

    def __init__(self) -> None:
        self.velocities = 0

    def write(self, record: Record) -> None:
        self.velocities += isinstance(record, VelocityRecord)

    def close(self) -> None:
        pass


def test_the_matrix_has_20_logs_with_source_licence_and_firmware() -> None:
    # 20 distinct public logs (a text dump of one of them is not another log), each
    # from its own repository path
    logs = [e for e in ENTRIES if "text_of" not in e]
    assert len(logs) >= 20 and len({e["source"] for e in logs}) == len(logs)
    assert len({e["file"] for e in ENTRIES}) == len(ENTRIES)
    for e in ENTRIES:
        assert e["source"] and e["firmware"] and e["vehicle"], e["file"]
        assert (DATA / e["licence_file"]).is_file(), e["licence_file"]
        assert e["expect"] in ("replays", "unsupported"), e["file"]
        assert (DATA / "matrix" / f"{e['file']}.xz").is_file(), e["file"]


def _within_bounds(s: LogReplaySummary) -> tuple[bool, str]:
    """Issue 33's bounds on a replay, and the figures."""
    rmse = s.rmse_vs_reference_in_flight_ned_mps.get("full")
    faults = s.vehicle_summary.faults if s.vehicle_summary is not None else []
    rejected = s.ekf_velocity_innovation_failures
    ok_rmse = rmse is not None and all(
        r <= b for r, b in zip(rmse, RMSE_BOUND_NED_MPS, strict=True)
    )
    ok_isolation = bool(rejected) or not faults
    text = f"full in flight {rmse}, isolations {len(faults)}, EKF velocity rejections {rejected}"
    return ok_rmse and ok_isolation, text


@pytest.mark.parametrize("entry", ENTRIES, ids=[e["file"] for e in ENTRIES])
def test_each_log_replays_or_names_what_it_lacks(
    entry: dict[str, Any], matrix_logs: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = matrix_logs / entry["file"]
    fmt = detect_format(path)
    if entry["expect"] == "unsupported":
        with pytest.raises(UnsupportedLogError) as err:
            if fmt == "tlog":
                check_tlog(path)
            else:
                replay_flight_log(path, load_config(None))
        assert str(err.value).startswith(f"{path}: unsupported: this log has no {entry['missing']}")
        capsys.readouterr()
        out = path.parent / f"{path.name}.jsonl"
        assert cli_main(["replay", str(path), "--no-progress", "--out", str(out)]) == 2
        stderr = capsys.readouterr().err
        assert "unsupported: this log has no" in stderr and "damaged" not in stderr
        assert not out.exists()  # refused before any output was created
        return
    sink = _Records()
    if fmt == "tlog":
        summary = replay_tlog(path, load_config(None), [sink], scan=check_tlog(path))
        assert summary.messages > 0 and not summary.cut and summary.vehicles
        # a vehicle was estimated from the recorded stream (IMU, attitude, velocity)
        assert sink.velocities > 0
        return
    s = replay_flight_log(path, load_config(None), [sink])
    assert sink.velocities > 0
    if entry["reference"]:
        assert s.sources["ekf"].startswith(entry["reference"]) and s.rates_hz.get("ekf")
    else:  # the reference topic is there, with no valid sample
        assert "ekf" not in s.rates_hz and "ekf" not in s.sources
        assert s.dropped.get("ekf_invalid", 0) > 0
    if not entry.get("bounds"):
        return
    # the bounds apply: the log has what they need (the matrix cannot claim otherwise)
    assert s.gps_nominal_rate_hz >= MIN_GPS_RATE_HZ and s.reference_samples_in_flight > 0
    ok, figures = _within_bounds(s)
    if "exceeds" in entry:
        assert not ok, f"{entry['file']} is now within the bounds ({figures}): update the matrix"
    else:
        assert ok, f"{entry['file']}: {figures}"


#: the matrix's columns in batch's summary (issue 33: log, firmware, vehicle, duration,
#: rates, reference, RMSE, isolations, refusals)
MATRIX_COLUMNS = (
    "log_id", "vehicle", "vehicle_type", "duration_s", "rate_imu_hz", "rate_gps_hz",
    "reference", "rmse_full_in_flight_n", "rmse_full_in_flight_e", "rmse_full_in_flight_d",
    "isolations", "ekf_velocity_rejections", "refusal",
)  # fmt: skip


def test_batch_over_mixed_logs_reports_every_one_with_the_matrix_columns(
    matrix_logs: Path, tmp_path: Path
) -> None:
    import csv

    from glmav_observer.commands.batch import run_batch

    names = [
        "copter-3.3-log171.bin", "px4-1.15-sitl-events.ulg", "plane-4.2.3-pilot_0004.BIN",
        "tlog-plane-2014-test.tlog",
    ]  # fmt: skip
    folder = tmp_path / "mixed"
    folder.mkdir()
    for n in names:
        (folder / n).write_bytes((matrix_logs / n).read_bytes())
    # a log cut inside a message (a full card, a pulled battery): its whole messages replay
    (folder / "cut.bin").write_bytes((matrix_logs / names[0]).read_bytes()[:200_001])
    # and a file that is no log at all, named explicitly: reported, the batch goes on
    (folder / "notes.bin").write_bytes(b"flight notes, not a log\n" * 10)
    rows = run_batch(sorted(folder.iterdir()), tmp_path / "out", workers=1)
    by_id = {r["log_id"]: r for r in rows}
    assert sorted(by_id) == sorted([*names, "cut.bin", "notes.bin"])
    with (tmp_path / "out" / "summary.csv").open() as f:
        header = next(csv.reader(f))
    assert set(MATRIX_COLUMNS) <= set(header)
    ok = by_id["copter-3.3-log171.bin"]
    assert ok["vehicle"] == "APM:Copter V3.3-dev" and ok["vehicle_type"] == "multirotor"
    assert ok["reference"] == "EKF1 core 0" and ok["ekf_velocity_rejections"] == 43
    assert ok["isolations"] == 5 and ok["rmse_full_in_flight_e"] > 0.3  # as the matrix says
    assert by_id["px4-1.15-sitl-events.ulg"]["vehicle"] == "PX4 v1.15.0"
    refused = by_id["plane-4.2.3-pilot_0004.BIN"]
    assert "unsupported: this log has no IMU data" in refused["refusal"]
    # a telemetry log without LOCAL_POSITION_NED: a refusal, and the batch went on
    tlog = by_id["tlog-plane-2014-test.tlog"]
    assert tlog["refusal"] == tlog["error"]
    assert tlog["refusal"].endswith(
        "tlog-plane-2014-test.tlog: unsupported: this log has no velocity measurement "
        "(LOCAL_POSITION_NED)"
    )
    cut = by_id["cut.bin"]
    assert cut["error"] is None and cut["vehicle"] == "APM:Copter V3.3-dev"
    assert 0 < cut["duration_s"] < ok["duration_s"]
    assert "not a log this reads" in by_id["notes.bin"]["error"]
