"""``glmav-observer batch``: the process pool and a Dask cluster of two workers on loopback
give the same Parquet dataset; a corrupt log is reported and does not stop the batch; the
HTML report holds a plot per replayed log."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pyarrow.dataset as pads
import pyarrow.parquet as pq
import pytest

from glmav_observer.cli import main as cli_main
from glmav_observer.commands.batch import run_batch


@pytest.fixture
def batch_inputs(public_logs: dict[str, Path], tmp_path: Path) -> Path:
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "copter.BIN").write_bytes(public_logs["dataflash"].read_bytes())
    (logs / "px4.ulg").write_bytes(public_logs["ulog"].read_bytes())
    # a dataflash log cut after its format messages: recognised, but no data to replay
    (logs / "corrupt.BIN").write_bytes(public_logs["dataflash"].read_bytes()[:3000])
    (logs / "README.md").write_text("flight campaign notes: not a log, skipped in a folder\n")
    return logs


def test_process_pool_and_dask_cluster_give_the_same_dataset(
    batch_inputs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pool_out = tmp_path / "pool"
    code = cli_main(
        ["batch", str(batch_inputs), "--out", str(pool_out), "--velocity-source", "ekf",
         "--workers", "2"]
    )  # fmt: skip
    assert code == 1  # a log failed (issue 31, D9: it was 0); the others are written
    printed = capsys.readouterr()
    assert "3 logs, 1 not replayed" in printed.out
    assert "glmav-observer batch: 1 of 3 logs not replayed" in printed.err
    assert "skipped 1 files in the folders given that are not logs" in printed.out
    assert "3/3 logs" in printed.err  # the progress bar reached the end

    with (pool_out / "summary.csv").open() as f:
        rows = {r["log_id"]: r for r in csv.DictReader(f)}
    assert set(rows) == {"copter.BIN", "corrupt.BIN", "px4.ulg"}
    assert "unsupported: this log has no ATT, AHR2, IMU or GPS" in rows["corrupt.BIN"]["error"]
    assert rows["copter.BIN"]["error"] == "" and rows["px4.ulg"]["error"] == ""
    assert rows["copter.BIN"]["rmse_basis"] == "truth"  # SIM2 in the ArduPilot SITL log
    assert rows["px4.ulg"]["rmse_basis"] == "reference"  # no truth in the PX4 log
    assert float(rows["copter.BIN"]["rate_gps_hz"]) == pytest.approx(5.0, rel=0.01)
    assert float(rows["px4.ulg"]["rate_imu_hz"]) == pytest.approx(250.0, rel=0.01)
    # the EKF fed to the observer against the SIM2 truth: measured 0.015, 0.017, 0.069
    # m/s (tests/unit/.../test_replay_logs.py bounds it by the EKF's own error)
    assert max(float(rows["copter.BIN"][f"rmse_active_{a}"]) for a in "ne") < 0.05

    data = pads.dataset(pool_out / "records").to_table()
    per_log = {lid: int(rows[lid]["records"]) for lid in ("copter.BIN", "px4.ulg")}
    counts = data.group_by("log_id").aggregate([("t_boot_s", "count")]).to_pylist()
    assert {c["log_id"]: c["t_boot_s_count"] for c in counts} == per_log
    assert set(data.column("vehicle").to_pylist()) == {"ArduCopter V4.6.0-dev", "PX4 v1.15.0"}

    report = (pool_out / "report.html").read_text()
    assert report.count("<img ") == 2  # a plot per replayed log, none for the corrupt one
    assert "not replayed: " in report

    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        dask_out = tmp_path / "dask"
        run_batch(
            sorted(f for f in batch_inputs.iterdir() if f.suffix != ".md"),
            dask_out,
            velocity_source="ekf",
            cluster=cluster.scheduler_address,
        )
    assert json.loads((dask_out / "summary.json").read_text()) == json.loads(
        (pool_out / "summary.json").read_text()
    )
    for name in ("copter.BIN.parquet", "px4.ulg.parquet"):
        a = pq.read_table(pool_out / "records" / name)
        b = pq.read_table(dask_out / "records" / name)
        assert a.num_rows > 1000
        assert a.equals(b), name


def test_batch_without_logs_or_with_a_missing_path_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main(["batch", str(empty), "--out", str(tmp_path / "o")]) == 2
    assert "no log files" in capsys.readouterr().err
    missing = tmp_path / "nope.ulg"
    assert cli_main(["batch", str(missing), "--out", str(tmp_path / "o")]) == 2
    assert f"{missing}: no such file" in capsys.readouterr().err


def _damaged_dataflash(src: Path, dst: Path) -> Path:
    """200 bits flipped in the data (past the format messages): still read, but
    pymavlink's indexer reports ~650 bad headers, one line each (measured for seed 1)."""
    import random

    data = bytearray(src.read_bytes())
    rng = random.Random(1)
    for _ in range(200):
        data[rng.randrange(20_000, len(data))] ^= 1 << rng.randrange(8)
    dst.write_bytes(bytes(data))
    return dst


def test_batch_counts_pymavlink_reports_and_on_a_full_disk_exits_2_with_its_summary(
    public_logs: dict[str, Path], tmp_path: Path
) -> None:
    """Issue 31, D9: pymavlink printed thousands of lines for a damaged log; a full disk
    (a 50 kB file-size limit: the summaries fit, the Parquet files do not) gave exit 2,
    no summary and a stray Parquet file."""
    import resource
    import signal
    import subprocess
    import sys

    logs = tmp_path / "logs"
    logs.mkdir()
    _damaged_dataflash(public_logs["dataflash"], logs / "damaged.BIN")
    (logs / "px4.ulg").write_bytes(public_logs["ulog"].read_bytes())
    obs = str(Path(sys.executable).with_name("glmav-observer"))

    def batch(out: Path, limit_bytes: int | None) -> subprocess.CompletedProcess[str]:
        def limit() -> None:  # in the child, before exec
            if limit_bytes is not None:
                signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG, not a killed process
                resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

        return subprocess.run(
            [obs, "batch", str(logs), "--out", str(out), "--no-progress", "--workers", "1"],
            check=False, capture_output=True, text=True, timeout=300, preexec_fn=limit,
        )  # fmt: skip

    ok = batch(tmp_path / "ok", None)
    assert ok.returncode == 0, ok.stderr
    assert ok.stderr == ""  # no pymavlink lines (there were ~650)
    with (tmp_path / "ok" / "summary.csv").open() as f:
        rows = {r["log_id"]: r for r in csv.DictReader(f)}
    counted = dict(kv.split("=") for kv in rows["damaged.BIN"]["dropped_while_reading"].split(", "))
    assert int(counted["dataflash_bad_headers"]) > 100

    out = tmp_path / "full"
    full = batch(out, 50_000)
    assert full.returncode == 2, full.stderr
    assert "Traceback" not in full.stderr
    assert "2 logs, 0 not replayed; could not write everything" in full.stdout  # the summary
    assert "  px4.ulg: PX4 " in full.stdout and "  damaged.BIN: ArduCopter" in full.stdout
    assert f"{out / 'records' / 'px4.ulg.parquet'}: not written (" in full.stderr
    assert "File too large" in full.stderr
    # whole files only: the summaries (1-2 kB) and the workers' log, no Parquet file,
    # nothing partial
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == ["batch.log", "summary.csv", "summary.json"]
    summary = json.loads((out / "summary.json").read_text())
    assert all("records_not_written" in r for r in summary)
