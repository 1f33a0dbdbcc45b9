"""Velocity-sensor faults injected by the real SITL, estimated live over UDP loopback.

Each fault (dropout, freeze, bias step 0.5 m/s, noise burst sigma 0.5 m/s) on each NED axis,
from t = 7 s of a climbing turn (the vehicle turns at 0.3 rad/s, so the accelerometer's
body-frame bias rotates in the earth frame): isolated within 0.5 s, on the right axis,
the active configuration switched to the one without that axis, with a jump of the
active estimate <= 0.05 m/s. And 10 minutes of healthy gusty flight (SITL as fast as
possible to a tlog, replayed) without a single false isolation.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from glmav_observer.app import Service
from glmav_sitl.config import data_path
from glmav_testkit.sitl_live import (
    SITL,
    fault_scenario,
    follow_tlog,
    run_live,
    service_test_config,
)

T_FAULT_S = 7.0
# bias 0.5 m/s: the bias test's threshold is max(0.15, 5 s) with s >= the measured residual
# spread (~0.05 m/s on this simulator), i.e. 0.25-0.3 m/s; a 0.3 m/s step sits at the edge
MAGNITUDE = {"dropout": 0.0, "freeze": 0.0, "bias": 0.5, "noise": 0.5}
CONFIG_WITHOUT = {"n": "c2", "e": "c3", "d": "c1"}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("kind", ["dropout", "freeze", "bias", "noise"])
@pytest.mark.parametrize("axis", ["n", "e", "d"])
def test_fault_isolated_and_handed_over(
    kind: str, axis: str, free_udp_port: Callable[[], int], tmp_path: Path
) -> None:
    scenario = fault_scenario(tmp_path, axis, kind, T_FAULT_S, MAGNITUDE[kind])
    run = run_live(scenario, port=free_udp_port(), tmp=tmp_path, duration_s=10.0, seed=11)
    v = run.summary.vehicles[1]
    assert v.faults, v.counters
    first = v.faults[0]
    assert first["axis"] == axis
    assert first["kind"] == kind
    # LOCAL_POSITION_NED at 30 Hz: the first faulty sample is at most 1/30 s after T_FAULT_S
    delay = first["t_detect_s"] - T_FAULT_S
    assert 0.0 <= delay <= 0.5, delay  # issue: isolated within 0.5 s
    sw = v.switches[0]
    assert sw["to"] == CONFIG_WITHOUT[axis]
    assert sw["jump_mps"] is not None and sw["jump_mps"] <= 0.05, sw  # issue bound
    assert v.active_config == CONFIG_WITHOUT[axis]  # the fault lasts to the end


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_ten_minutes_of_healthy_flight_without_false_isolation(tmp_path: Path) -> None:
    """600 s of the gusts scenario, SITL as fast as possible into a tlog, which the service
    reads as it grows (the simulator on one core, the estimation on the other; every
    record seen, unlike a UDP link at full speed).

    The SITL's RAW_IMU, SCALED_IMU and SERVO_OUTPUT_RAW streams are switched off in its
    config (the service uses HIGHRES_IMU and, by default, no actuator outputs): half the
    messages to simulate and estimate.
    """
    sitl_toml = data_path("sitl.toml").read_text(encoding="utf-8")
    sitl_toml = re.sub(r"(?m)^(raw_imu|scaled_imu|servo_output_raw) = .*$", r"\1 = 0.0", sitl_toml)
    (tmp_path / "sitl.toml").write_text(sitl_toml, encoding="utf-8")
    path = tmp_path / "gusts-600s.tlog"
    service = Service(service_test_config())
    sim = subprocess.Popen(
        [SITL, "run", "--scenario", "gusts", "--duration", "600", "--speed", "max",
         "--seed", "21", "--config", str(tmp_path / "sitl.toml"), "--tlog", str(path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        for rec in follow_tlog(path, sim):
            service.feed_message(rec.msg, rec.t_host_us * 1e-6, str(path))
    finally:
        if sim.poll() is None:
            sim.kill()
        _, err = sim.communicate(timeout=60)
        service.close()
    assert sim.returncode == 0, err.decode(errors="replace")[-2000:]
    v = service.summary().vehicles[1]
    assert v.truth_samples > 29_000  # ~597 s of SIM_STATE at 50 Hz
    assert v.faults == [], v.faults
    assert v.switches == []
    rmse = v.rmse_ned_mps["active"]
    assert rmse is not None and max(rmse) <= 0.1, rmse
