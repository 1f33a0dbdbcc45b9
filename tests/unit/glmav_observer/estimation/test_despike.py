"""IMU shock rejection."""

from __future__ import annotations

import numpy as np

from glmav_observer.estimation.despike import Despiker


def test_a_single_spike_is_held_out_and_a_real_step_is_accepted_one_sample_late() -> None:
    d = Despiker()
    rng = np.random.default_rng(1)
    base = np.array([0.0, 0.0, -9.81])
    for _ in range(200):
        assert d.filter(tuple(base + rng.normal(0, 0.2, 3))) is not None
    assert d.filter((500.0, 0.0, -9.81)) is None  # a shock: held out
    assert d.filter(tuple(base)) is not None  # back to normal: used
    launch = (150.0, 0.0, -9.81)  # a real step (launch): the second sample confirms it
    assert d.filter(launch) is None
    assert d.filter(launch) == launch


def test_the_threshold_follows_a_vibrating_imu() -> None:
    d = Despiker()
    rng = np.random.default_rng(2)
    for _ in range(500):
        d.filter(tuple(rng.normal(0, 5.0, 3)))  # SIM_ACC1_RND = 5 m/s² per axis
    # ‖Δf‖ RMS = √6·5 ≈ 12.2 m/s²; threshold 8× that, within sampling scatter
    assert 85.0 <= d.threshold_mps2() <= 110.0
    assert 20.0 <= d.noise_var_mps2() <= 30.0  # σ_f² = 25
