"""Damaged MAVLink against the real ``glmav-observer serve`` over UDP loopback, in the
default worker mode (one worker per usable core: 2 on the test machine) and with one
worker (issue 31: "fuzz re-run in the default worker mode").

The vehicle (system id 1, the simulator's 4 s ``cruise`` stream at its own rate) is
interleaved with three damaged datagrams after every valid frame
(``glmav_testkit.fuzzgen``, vehicle-safe: nothing that passes the CRC carries the
vehicle's ids with a usable stamp). The long form is ``python -m benchmarks.fuzz_ingest
--serve`` (docs/benchmarks/fuzz_ingest.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from glmav_testkit import REPO_ROOT
from glmav_testkit.fuzzgen import load_corrupt_log, sitl_stream
from glmav_testkit.serve_fuzz import clean_series, make_plan, run_session
from glmav_testkit.serve_process import usable_cores

VEHICLE_S = 4.0
#: the default ``[ingest] max_vehicles``
MAX_VEHICLES = 8


@pytest.mark.timeout(240)
@pytest.mark.parametrize("workers", [None, 1], ids=["default-workers", "one-worker"])
def test_serve_survives_fuzz_counts_every_rejection_and_keeps_the_vehicle(
    workers: int | None, tmp_path: Path
) -> None:
    stream = sitl_stream("cruise", VEHICLE_S, seed=1)
    corrupt = load_corrupt_log(REPO_ROOT / "tests" / "data" / "real-tlogs")
    plan = make_plan(stream, VEHICLE_S, corrupt, seed=7, vehicle_safe=True)
    assert plan.cases > 2.5 * len(stream.frames)  # 3 per valid frame after the first 50
    assert len(plan.kinds) == 13  # every kind of damage (13 kinds, ~900 cases each)

    r = run_session(plan, workers, tmp_path)
    stderr = r.stopped.stderr
    n_workers = usable_cores() if workers is None else workers
    if workers is None:  # serve chose, and said so
        assert f"serve: {n_workers} worker process(es): {n_workers} usable cores" in stderr
    if n_workers > 1:  # the default mode is the worker mode here (a 2-core machine)
        assert len(r.stopped.summary.workers) == n_workers, r.stopped.summary.text[-2000:]

    # no crash: alive after the traffic, exit 0 after SIGTERM with its summary, no traceback
    assert r.alive_after_traffic
    assert r.stopped.returncode == 0, stderr[-3000:]
    assert r.stopped.summary.present, r.stopped.summary.text[-2000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    # the sender holds back while 1 MB of the 4 MB receive buffer is queued: the kernel
    # drops nothing unless the service stops reading
    assert r.kernel_drops == 0
    # every rejection counted, reason by reason, exactly as the service's own decoder
    # frames the same datagrams in this process (summed over the workers)
    assert r.framing() == plan.expected, (r.framing(), plan.expected)
    assert r.stopped.summary.rejected_frames == sum(
        plan.expected.get(k, 0) for k in ("bad_crc", "bad_header", "truncated")
    )
    assert r.stopped.summary.rejected_frames > 0.5 * plan.cases  # most cases are damaged
    assert r.stopped.summary.messages == plan.expected["frames_ok"]
    # the storm of system ids: the vehicle cap holds for the service, whatever the workers
    assert 1 in r.stopped.summary.vehicles
    assert len(r.stopped.summary.vehicles) <= MAX_VEHICLES
    assert r.stopped.summary.service.get("vehicle_cap_dropped", 0) > 0
    # the vehicle's estimates are those of its clean stream, record for record (the
    # estimator runs on the vehicle's clock; ~250 Hz IMU over 4 s, first 0.1 s warming up)
    clean = clean_series(stream)
    assert len(clean) > 0.9 * 250 * VEHICLE_S
    assert r.vehicle_series == clean
