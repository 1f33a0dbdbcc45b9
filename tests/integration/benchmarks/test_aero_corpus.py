"""The short CI version of ``benchmarks/aero.py``: two ArduPilot SITL flights through the
service's ingest, the drag model and the aided filter, against SIM_STATE truth, all 15
loss cases each: the coax (whose body drag the fit identifies to σ_f ≈ 0.01 m/s²: the
bounds) and the quad into which a 4 m/s wind is switched on mid-flight (the safety rules:
never worse than dead reckoning), and one of the wind tuning flights (a hexa in a steady
5 m/s wind: ``refuse_negative_k``)."""

from __future__ import annotations

import math
import statistics

import pytest
from benchmarks.aero import (
    BOUND_10S_MEDIAN,
    BOUND_10S_WORST,
    BOUND_60S,
    CORPUS,
    WORSE_TOL_MPS,
    flight_from_samples,
    run_flight,
    tlog_samples,
    wind_tuning_flights,
)

from glmav_observer.estimation.aero import DragModelConfig
from glmav_testkit.fault_replay import read_log_bytes


def _cases(name: str) -> list[dict[str, object]]:
    data = read_log_bytes(CORPUS / f"{name}.tlog.xz")
    return run_flight(flight_from_samples(name, "ardupilot", tlog_samples(data)))


@pytest.fixture(scope="module")
def cases() -> list[dict[str, object]]:
    return _cases("f_coax_clean")


def test_aided_cases_meet_the_issue_bounds(cases: list[dict[str, object]]) -> None:
    aided = [c for c in cases if c["axis"] != "d" and float(c["aided_fraction"]) > 0.5]  # type: ignore[arg-type]
    # the three later loss times, n and e (the two earliest learn only along one body axis
    # and are refused by the model's own test: measured 6 aided cases)
    assert len(aided) >= 5
    e10 = [float(c["err10_aided_mps"]) for c in aided]  # type: ignore[arg-type]
    e60 = [float(c["err60_aided_mps"]) for c in aided]  # type: ignore[arg-type]
    # issue 13's bounds themselves (measured: median 0.04, worst 0.13 at 10 s; worst 0.14
    # at 60 s; dead reckoning on the same cases reaches 0.71 at 60 s)
    assert statistics.median(e10) <= BOUND_10S_MEDIAN
    assert max(e10) <= BOUND_10S_WORST
    assert max(e60) <= BOUND_60S


def test_never_worse_than_dead_reckoning_and_sigma_covers(
    cases: list[dict[str, object]],
) -> None:
    assert len(cases) == 15
    for c in cases:
        # the benchmark's criterion: RMS over the 60 s within 0.02 m/s of dead reckoning's
        # or better (measured: aided ≤ DR in every case of this flight)
        assert float(c["rms_aided_mps"]) <= float(c["rms_dr_mps"]) + WORSE_TOL_MPS, c  # type: ignore[arg-type]
        # |error| ≤ 2σ at least 95 % of the time (measured: 1.0 in every case)
        assert float(c["cover2_aided"]) >= 0.95, c  # type: ignore[arg-type]
        # nothing stopped the aiding on this flight (the safety rules raise no false alarm)
        assert not c["stop_reason"], c


def test_a_wind_switched_on_mid_flight_is_not_worse_than_dead_reckoning() -> None:
    cases = _cases("a_quad_wind")
    assert len(cases) == 15
    for c in cases:
        # before the safety rules 2 of these were worse than dead reckoning (60 s RMS 0.64
        # and 0.81 vs 0.21 and 0.24 m/s; 10 s error 0.48 vs 0.07); now the model, which
        # its data contradicted when the wind came on (51 and 90 outliers in the 5 s
        # spans after 63.7 s), refuses itself for the later losses
        assert float(c["rms_aided_mps"]) <= float(c["rms_dr_mps"]) + WORSE_TOL_MPS, c  # type: ignore[arg-type]
        assert float(c["err10_aided_mps"]) <= float(c["err10_dr_mps"]) + WORSE_TOL_MPS, c  # type: ignore[arg-type]
        assert float(c["err60_aided_mps"]) <= float(c["err60_dr_mps"]) + WORSE_TOL_MPS, c  # type: ignore[arg-type]
        assert float(c["cover2_aided"]) >= 0.95, c  # type: ignore[arg-type]
    # the losses after the wind came on (65.1, 69.5, 73.8 s) are refused as changing
    late = [c for c in cases if float(c["t_loss_s"]) > 64.0]  # type: ignore[arg-type]
    assert late and all("changing" in str(c["trust_reason"]) for c in late), late


def test_a_steady_wind_on_a_hexa_is_not_worse_than_dead_reckoning() -> None:
    # the wind tuning flight whose aiding was furthest above dead reckoning: a hexa in a
    # 5 m/s wind (turbulence 1.5). The ground-speed quadratic (A2) does not hold in that
    # wind and the y row's learnt k is clearly negative (down to −1.8 1/s, z −39)
    fl = wind_tuning_flights(["k_hexa_wind5"])[0]
    off = DragModelConfig(refuse_negative_k=False)
    for config, worst_min, worst_max in ((None, -math.inf, WORSE_TOL_MPS), (off, 0.3, math.inf)):
        cases = [c for c in run_flight(fl, model_config=config) if c["axis"] != "d"]
        assert len(cases) == 10
        worst = max(float(c["rms_aided_mps"]) - float(c["rms_dr_mps"]) for c in cases)
        # with the default refuse_negative_k: issue 32's bound on every loss (measured: no
        # pseudo-measurement, the aided axis is the dead reckoning, excess 0); without it
        # the model's pseudo-measurements lead the n axis away (measured excess 0.77 m/s
        # RMS, 1.8 m/s at +60 s against dead reckoning's 0.2): more than 0.3 shows the guard
        # is what keeps it off
        assert worst_min < worst <= worst_max, (config, worst)


def test_a_model_whose_validation_is_inconsistent_is_not_used() -> None:
    # the coax in a steady 3 m/s wind, its later losses (after 100-160 s of flight): no
    # row's k is negative, but the x row's pseudo-measurements are off by 2-3 times their
    # σ against the validation (held out in time: NEES 4-25). Inflating σ by √NEES (the
    # old nees_max of 25) let the filter average a bias in
    fl = wind_tuning_flights(["j_coax_wind3"])[0]
    old = DragModelConfig(nees_max=25.0)
    for config, worst_min, worst_max in ((None, -math.inf, WORSE_TOL_MPS), (old, 0.1, math.inf)):
        cases = [c for c in run_flight(fl, model_config=config, late=True) if c["axis"] != "d"]
        assert len(cases) == 6
        worst = max(float(c["rms_aided_mps"]) - float(c["rms_dr_mps"]) for c in cases)
        # nees_max 4 (a consistent model's 3σ): issue 32's bound on every loss (measured
        # excess ≤ 0); at 25, above dead reckoning's RMS by more than 0.1 (measured 0.17)
        assert worst_min < worst <= worst_max, (config, worst)
