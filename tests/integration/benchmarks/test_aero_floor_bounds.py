"""The short CI version of issue 32's comparison in ``benchmarks/aero.py``: every loss of
three flights, n, e and d, against its floor (``benchmarks/aero_floor.py``): one of the
ArduPilot tuning set (the coax), one of the held-out set (the coax in a 2 m/s wind: judged,
never tuned on) and glmav-sitl's `gusts` hover (ideal sensors, cyclic regressors, the
vehicle file's k), the case where the aiding used to be refused while the floor showed the
information there."""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import Any

import pytest
from benchmarks.aero import (
    CORPUS,
    HELDOUT,
    HORIZON_S,
    Flight,
    flight_from_samples,
    run_flight,
    set_of,
    sidecar_dir_of,
    sim_flights,
    tlog_samples,
)
from benchmarks.aero_floor import (
    COVER_MIN,
    FLOOR_APPLIES_BELOW,
    WORSE_TOL_MPS,
    floor_of_case,
    judge_groups,
)

from glmav_testkit.fault_replay import read_log_bytes


def _judged(fl: Flight) -> list[dict[str, Any]]:
    return [
        c | {"set": set_of(fl)} | floor_of_case(fl, c, HORIZON_S, sidecar_dir_of(fl))
        for c in run_flight(fl)
    ]


@pytest.fixture(scope="module")
def cases() -> list[dict[str, Any]]:
    out = []
    for directory, name, source in (
        (CORPUS, "f_coax_clean", "ardupilot"),
        (HELDOUT, "hd_coax_wind2", "ardupilot-heldout"),
    ):
        samples = tlog_samples(read_log_bytes(directory / f"{name}.tlog.xz"))
        out += _judged(flight_from_samples(name, source, samples))
    with tempfile.TemporaryDirectory(prefix="aero-floor-") as tmp:
        gusts = sim_flights("gusts", None, 1, Path(tmp))
    out += _judged(next(fl for fl in gusts if fl.source == "glmav-sitl+cyclic"))
    return out


def test_never_worse_than_dead_reckoning_and_sigma_covers(cases: list[dict[str, Any]]) -> None:
    # 3 flights × 5 losses × (n, e, d)
    assert len(cases) == 45
    for c in cases:
        # issue 32's bound itself, every loss (measured: at most 0.012 m/s above DR's)
        assert c["rms_aided_mps"] <= c["rms_dr_mps"] + WORSE_TOL_MPS, c
    for flight in {c["flight"] for c in cases}:
        cs = [c for c in cases if c["flight"] == flight]
        # |e| ≤ 2σ over 95 % of the samples of the flight's losses (equal lengths: the mean
        # of the per-loss fractions; measured ≥ 0.99 on all three)
        assert statistics.fmean(c["cover2_aided"] for c in cs) >= COVER_MIN, flight


def test_the_aiding_engages_where_the_floor_says_the_information_is(
    cases: list[dict[str, Any]],
) -> None:
    groups = {(g["flight"], g["axis"]): g for g in judge_groups(cases)}
    for flight in ("f_coax_clean", "gusts/ideal +cyclic"):
        for axis in "ne":
            g = groups[(flight, axis)]
            # the floor is far below dead reckoning: the information is there (measured:
            # floor +60 0.002 m/s on the coax, 0.23 in gusts; DR 0.35-1.6)
            assert g["floor +60"] < FLOOR_APPLIES_BELOW * g["DR +60"], g
            # the aiding engages in most losses (measured 3 of 5 on each; before issue 32
            # none in gusts: every pseudo-measurement's σ was over the 1 m/s cap)
            assert g["aided > 50 %"] >= 3, g
            # and more than halves dead reckoning's median error at +60 s (measured
            # aided/DR 0.14 and 0.16 on the coax, 0.34 and 0.48 in gusts). Issue 32's
            # bound, ≤ 1.5 × the floor, is not met (aided/floor 1.7 and 3.2 in gusts, ~60 on
            # the coax: docs/benchmarks/aero.md says why)
            assert g["aided +60"] <= 0.5 * g["DR +60"], g


def test_the_causal_floor_grants_only_the_past(cases: list[dict[str, Any]]) -> None:
    groups = {(g["flight"], g["axis"]): g for g in judge_groups(cases)}
    for axis in "ne":
        g = groups[("f_coax_clean", axis)]
        # a law fitted before the loss knows less than one fitted over the whole flight:
        # the causal floor is above the as-flown one, which is above the oracle's
        # (measured medians +60: oracle 0.002, as-flown 0.020-0.024, causal 0.040-0.056)
        assert g["floor +60"] < g["as-flown +60"] < g["causal +60"], g
    for c in cases:
        if c["flight"] != "f_coax_clean" or c["axis"] == "d":
            continue
        if float(c["aided_fraction"]) > 0.5:
            # where the coax's loss is aided the causal floor says the information is there
            # (measured causal +60 0.024-0.056 against dead reckoning's 0.17-1.05)
            assert c["causal_median60_mps"] < FLOOR_APPLIES_BELOW * c["err60_dr_mps"], c
