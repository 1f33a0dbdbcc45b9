"""Our simulator's ``autopilot`` sensor profile, flown and replayed through the service.

The profile's LOCAL_POSITION_NED is a 10 Hz GPS through a filter, 150 ms late against
truth (``[autopilot] velocity_lag_s``). Unmodelled, that lag reads as a velocity step at
every strong acceleration: in a gun launch (≈13 m/s² of deceleration) 0.15 s is 2 m/s,
and before the fit modelled the lag the service isolated a false bias on d at 3.3 s and
dead-reckoned d 4.2 m/s RMS off for the rest of the flight. The FDI's reference fit now
learns the lag (fdi module docstring) and the bank takes the measurement moved to the
present by it (``compensate_lag``). Real parts: the simulator's own runner writes a
tlog, the service replays it (glmav_testkit.fault_replay.replay).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from glmav_observer.config import ServiceConfig
from glmav_sitl.runner import run
from glmav_sitl.scenario import load_scenario, load_sitl_config
from glmav_testkit.fault_replay import LogResult, replay

#: the profile's lag (sim_bridge/glmav_sitl/data/sitl.toml [autopilot] velocity_lag_s)
PROFILE_LAG_S = 0.15


def _fly(tmp_path: Path, scenario: str, duration_s: float, seed: int) -> Path:
    sc = dataclasses.replace(
        load_scenario(scenario), sensor_profile="autopilot", duration_s=duration_s
    )
    tlog = tmp_path / f"{scenario}-{seed}.tlog"
    run(sc, speed="max", seed=seed, tlog_path=tlog)
    return tlog


def _without_lag_compensation() -> ServiceConfig:
    cfg = ServiceConfig()
    est = dataclasses.replace(cfg.estimation, compensate_lag=False)
    return dataclasses.replace(cfg, estimation=est)


@pytest.fixture(scope="module")
def launch(tmp_path_factory: pytest.TempPathFactory) -> tuple[LogResult, LogResult]:
    tlog = _fly(tmp_path_factory.mktemp("launch"), "launch", 20.0, seed=0)
    return replay(tlog), replay(tlog, _without_lag_compensation())


def test_a_launch_on_late_gps_isolates_nothing_and_learns_the_lag(
    launch: tuple[LogResult, LogResult],
) -> None:
    res, _ = launch
    assert res.isolations == [], res.isolations
    assert res.switches == []
    fit = res.reference_fit
    assert fit is not None
    # The fit learns the lag of y behind the IMU's own reconstruction, and its regressor
    # L (the mean acceleration over the last 0.1 s, from a 50 Hz point-sampled vibrating
    # IMU) carries noise that attenuates the estimate (errors in variables): 0.094-0.106 s
    # measured for the profile's 0.15 s over seeds 0-2 (with a 0.2 s window: 0.105-0.118,
    # but a compensation lagged by 0.1 s). Bound: clearly observed (≥ 0.06 s, 3σ) and not
    # above the truth (+ 1σ of the fit, 0.02 s).
    assert 0.06 <= fit.measurement_lag_s <= PROFILE_LAG_S + 0.02, fit
    assert fit.measurement_lag_sigma_s <= 0.021  # the memory's floor (FdiTuning.lag_sigma_min_s)


def test_a_launch_on_late_gps_is_estimated_at_the_profiles_noise(
    launch: tuple[LogResult, LogResult],
) -> None:
    res, plain = launch
    assert res.rmse_ned_mps["full"] is not None and plain.rmse_ned_mps["full"] is not None
    d_rmse = res.rmse_ned_mps["full"][2]
    # the profile's filtered GPS gives `full` 0.06 m/s on d in a hover (the accuracy
    # suite): with the lag compensated the launch adds at most as much again (second-
    # order terms of the lag model during 13 m/s² of deceleration): bound 2 × 0.06
    assert d_rmse <= 0.12, res.rmse_ned_mps
    # without the compensation the 150 ms lag itself stays in `full` (0.2 m/s measured):
    # the compensation is what buys the accuracy, not a coincidence of this seed
    assert plain.rmse_ned_mps["full"][2] >= 1.5 * d_rmse, (plain.rmse_ned_mps, d_rmse)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_cruise_on_late_gps_isolates_nothing(tmp_path: Path, seed: int) -> None:
    """The cruise's first acceleration (to 3 m/s north at ~1 m/s²) read as a bias on n at
    3.8 s on every seed before the lag was modelled."""
    res = replay(_fly(tmp_path, "cruise", 20.0, seed))
    assert res.isolations == [], res.isolations
    fit = res.reference_fit
    # the cruise's accelerations are 10× smaller than the launch's: 0.068-0.081 s measured
    assert fit is not None and 0.04 <= fit.measurement_lag_s <= PROFILE_LAG_S + 0.02, fit


def test_an_isolation_on_a_lost_attitude_is_withdrawn(tmp_path: Path) -> None:
    """The profile with its GPS filter off (τ = 0, lag 0.1 s; not the default): in the
    launch's ballistic phase the attitude estimator tilts, n's residual ramps and n is
    isolated at 3.6 s. Dead-reckoned on the lost attitude, n stayed 2.66 m/s RMS off for
    the rest of the flight. A velocity sensor's fault is an offset or noise; a residual
    that ramps at more than ramp_limit_mps2 over ramp_window_s is the IMU's path, and the
    isolation is withdrawn (fdi.FaultDetector._decide)."""
    sitl = load_sitl_config()
    ap = dataclasses.replace(sitl.autopilot, velocity_lag_s=0.1, velocity_filter_tau_s=0.0)
    sc = dataclasses.replace(load_scenario("launch"), sensor_profile="autopilot", duration_s=10.0)
    tlog = tmp_path / "launch-nofilter.tlog"
    run(sc, speed="max", seed=0, tlog_path=tlog, sitl=dataclasses.replace(sitl, autopilot=ap))
    res = replay(tlog)
    assert res.counters.get("fdi_ramp_withdrawals", 0) >= 1, res.counters
    assert res.rmse_ned_mps["full"] is not None
    # n is true 0 (a vertical launch); `full` itself drifts to 0.45 m/s on the tilted
    # attitude before the isolation (measured with every FDI decision as before), and
    # the withdrawal 1 s after the isolation leaves it 0.475 m/s RMS (was 2.66): bound
    # 0.7, far under what a kept isolation costs
    assert res.rmse_ned_mps["full"][0] <= 0.7, res.rmse_ned_mps
