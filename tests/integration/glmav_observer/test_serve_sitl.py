"""The daemon against the real SITL over UDP loopback: accuracy, replay equality, two vehicles."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from glmav_observer.app_replay import replay_tlog
from glmav_observer.publish.file_sink import FileSink
from glmav_observer.records import VelocityRecord, flatten
from glmav_testkit.sitl_live import MemorySink, run_live, service_test_config


@pytest.mark.timeout(180)
@pytest.mark.parametrize("scenario", ["hover", "cruise", "gusts"])
def test_active_estimate_rmse_against_sim_state(
    scenario: str, free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    run = run_live(scenario, port=free_udp_port(), tmp=tmp_path, duration_s=20.0, seed=3)
    # nothing lost (the SITL also answers our SET_MESSAGE_INTERVAL with COMMAND_ACKs, which
    # its message count leaves out)
    assert run.summary.link_counters["udp"]["frames_ok"] >= run.sent_messages
    v = run.summary.vehicles[1]
    rmse = v.rmse_ned_mps["active"]
    assert rmse is not None and v.truth_samples > 500  # 17 s of SIM_STATE at 50 Hz
    # issue: <= 0.1 m/s per axis with default noise (analysis: ~0.02 for gamma_full = 12,
    # sigma_y = 0.05 m/s at 30 Hz; docs/design/observer-notes.md)
    assert max(rmse) <= 0.1, rmse
    assert v.faults == []  # healthy sensors: no isolation
    assert v.active_config == "full"


@pytest.mark.timeout(180)
def test_replay_of_the_sitl_tlog_equals_the_live_run_and_is_byte_identical(
    free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    run = run_live("cruise", port=free_udp_port(), tmp=tmp_path, duration_s=12.0, seed=5)
    assert run.summary.link_counters["udp"]["frames_ok"] >= run.sent_messages
    replayed = MemorySink()
    replay_tlog(run.tlog, service_test_config(), [replayed])
    live_v = [flatten(r) for r in run.records if isinstance(r, VelocityRecord)]
    replay_v = [flatten(r) for r in replayed.records if isinstance(r, VelocityRecord)]
    assert len(live_v) > 2000  # 12 s of 250 Hz IMU, 5 records each
    assert live_v == replay_v  # the same estimates, bit for bit
    outs = []
    for i in range(2):
        out = tmp_path / f"replay{i}.csv"
        replay_tlog(run.tlog, service_test_config(), [FileSink(out)])
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]
    assert len(outs[0]) > 100_000


@pytest.mark.timeout(180)
def test_two_vehicles_are_estimated_independently(
    free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    run = run_live(
        "hover",
        port=free_udp_port(),
        tmp=tmp_path,
        duration_s=10.0,
        seed=7,
        sysids=(1, 2),
        speed="2",
    )
    assert sorted(run.summary.vehicles) == [1, 2]
    for sysid in (1, 2):
        v = run.summary.vehicles[sysid]
        rmse = v.rmse_ned_mps["active"]
        assert rmse is not None and max(rmse) <= 0.1, (sysid, rmse)
        assert v.faults == []
    # independent: each vehicle's records are its own (different seeds -> different noise)
    a = [r.v_ned_mps for r in run.records if isinstance(r, VelocityRecord) and r.sysid == 1]
    b = [r.v_ned_mps for r in run.records if isinstance(r, VelocityRecord) and r.sysid == 2]
    assert len(a) > 1000 and len(b) > 1000
    assert a[:100] != b[:100]
