"""Short CI version of the paper reproduction (docs/paper-reproduction.md).

The simulator flies the ``paper`` scenario (eq. (48), RK4 1e-4 s, 10 kHz streams) for 1 s
into a real tlog; the service's ingest decodes it and its estimator runs as the paper's
three observers (γ = 90, 70, 70, x̂0 = 0, eq. (49)) through ``benchmarks.paper``.
Asserted: the measured axes fall below 1 % of their initial error within the time γ
predicts, ln(100)/γ; the lost axis keeps its initial error (exact E); with the small-angle
E (15) at φ0 = 1.3 rad nothing converges. All as the doc states.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from benchmarks.paper import (
    LOST_INDEX,
    PAPER_CONFIGS,
    PAPER_GAMMA,
    PaperRun,
    lost_axis_error,
    measured_axis_decay,
    replay_paper,
    simulate_paper,
    tlog_samples,
)

from glmav_observer.ingest.samples import AttitudeSample, ImuSample, Sample, VelocitySample

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> list[Sample]:
    tlog: Path = tmp_path_factory.mktemp("paper") / "paper.tlog"
    sim = simulate_paper(tlog, duration_s=1.0, seed=0)
    assert sim["steps"] == 10_000  # 1 s of RK4 at 1e-4 s
    out, _ = tlog_samples(tlog)
    return out


@pytest.fixture(scope="module")
def exact(samples: list[Sample]) -> PaperRun:
    return replay_paper(samples, "exact")


def test_streams_reach_the_observer_at_the_documented_rates(samples: list[Sample]) -> None:
    # HIGHRES_IMU carries time_usec: all 10 001 samples of 1 s at 10 kHz arrive. ATTITUDE
    # and LOCAL_POSITION_NED carry time_boot_ms: ten share a stamp, the first is kept (1 kHz).
    n_imu = sum(isinstance(s, ImuSample) for s in samples)
    n_att = sum(isinstance(s, AttitudeSample) for s in samples)
    n_vel = sum(isinstance(s, VelocitySample) for s in samples)
    assert (n_imu, n_att, n_vel) == (10_001, 1_001, 1_001)


def test_measured_axes_fall_below_one_percent_within_the_time_gamma_predicts(
    exact: PaperRun,
) -> None:
    for c in PAPER_CONFIGS:
        d = measured_axis_decay(exact, c)
        predicted = math.log(100.0) / PAPER_GAMMA[c]  # ‖Dε‖ = e0 e^{−γt} for the exact E
        # ±10 %: the 1 kHz hold of y and E leaves a floor of ≈ 0.2 % of e0 (final value
        # below), which moves the 1 % crossing by ≤ ln(1/(1 − 0.2))/γ ≈ 0.22/γ (4.8 %), and
        # y arrives every 1 ms (≤ 2 % of 0.05 s)
        assert 0.9 * predicted <= d["t_1pct_stays_s"] <= 1.1 * predicted, (c, d)
        assert d["final_mps"] < 0.005 * d["e0_mps"], (c, d)  # the hold floor, well below 1 %
        # decay rate fitted between 30 % and 3 % of e0: γ within 15 % (the floor bends it)
        assert abs(d["fitted_rate_1ps"] / PAPER_GAMMA[c] - 1.0) < 0.15, (c, d)


def test_lost_axis_keeps_its_initial_error_with_the_exact_e(
    exact: PaperRun, samples: list[Sample]
) -> None:
    w_max = max(
        float(np.linalg.norm(s.omega_body_radps)) for s in samples if isinstance(s, ImuSample)
    )
    for c in PAPER_CONFIGS:
        e0 = lost_axis_error(exact, c, 0.0)
        e1 = lost_axis_error(exact, c, 1.0)
        d = measured_axis_decay(exact, c)
        # ε̇_l = (ω_e × Dε)_l, so |Δε_l| ≤ max|ω| ∫‖Dε‖dt = max|ω| e0_meas/γ, plus the drift
        # of the 1 kHz attitude hold (docs/design/observer-notes.md: ≤ ~1e-3 m/s per second here, ×5)
        bound = w_max * d["e0_mps"] / PAPER_GAMMA[c] + 5e-3
        assert abs(e1 - e0) <= bound, (c, e0, e1, bound)
        assert abs(e0) > 1.0  # the paper's (48) leaves > 1 m/s on every lost axis...
        assert abs(e1) > 0.99 * abs(e0) - bound  # ...and it is still there at 1 s (no convergence)


def test_small_angle_e_converges_on_nothing_at_phi0_1_3_rad(samples: list[Sample]) -> None:
    run = replay_paper([s for s in samples if s.t_boot_s <= 0.5], "small_angle")
    for c in PAPER_CONFIGS:
        d = measured_axis_decay(run, c)
        # (15) is off by O(1) at φ = 1.3 rad: the measured-axis error never reaches 1 %
        # (the doc reports ≥ 1.5 m/s at 1 s); at 0.5 s it is still above 10 % of e0
        assert math.isnan(d["t_1pct_first_s"]), (c, d)
        assert d["final_mps"] > 0.1 * d["e0_mps"], (c, d)
        lost = LOST_INDEX[c]
        assert lost in (0, 1, 2)
