"""The short CI version of ``benchmarks/aero.py``: one ArduPilot SITL flight (the coax,
whose body drag the fit identifies to σ_f ≈ 0.01 m/s²), all 15 loss cases through the
service's ingest, the drag model and the aided filter, against SIM_STATE truth."""

from __future__ import annotations

import statistics

import pytest
from benchmarks.aero import (
    BOUND_10S_MEDIAN,
    BOUND_10S_WORST,
    BOUND_60S,
    CORPUS,
    flight_from_samples,
    run_flight,
    tlog_samples,
)

from glmav_observer.evaluation import read_log_bytes


@pytest.fixture(scope="module")
def cases() -> list[dict[str, object]]:
    data = read_log_bytes(CORPUS / "f_coax_clean.tlog.xz")
    return run_flight(flight_from_samples("f_coax_clean", "ardupilot", tlog_samples(data)))


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
        assert float(c["rms_aided_mps"]) <= float(c["rms_dr_mps"]) + 0.02, c  # type: ignore[arg-type]
        # |error| ≤ 2σ at least 95 % of the time (measured: 1.0 in every case)
        assert float(c["cover2_aided"]) >= 0.95, c  # type: ignore[arg-type]
