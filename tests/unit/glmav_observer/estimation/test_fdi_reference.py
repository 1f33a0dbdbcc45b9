"""The FDI's reference fit and the dead reckoning's σ on constructed data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from glmav_observer.estimation.fdi_reference import (
    LAG,
    LAG_WINDOW_S,
    ReferenceFit,
    dead_reckoning_age_s,
    sigma_dead_reckoning_mps,
)
from glmav_observer.estimation.fdi_types import FdiConfig


def test_reference_uncertainty_grows_into_an_unobserved_heading_error() -> None:
    """Hover (no horizontal acceleration): the heading error is unobserved, its posterior
    stays at the prior (0.1 rad); predicting into an acceleration is then uncertain by
    ~σ_ψ·|∫a_h dt|, which the tests add to their threshold."""
    cfg = FdiConfig()
    fit = ReferenceFit(cfg)
    b_int = (0.0,) * 9
    for k in range(100):  # 4 s of hover at 25 Hz, three axes
        t = k / 25.0
        E = np.eye(3) * t
        for j in range(3):
            fit.add(t, j, 0.0, (tuple(E.ravel().tolist()), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), 0.03)
    fit.prune_and_fit(4.0)
    assert fit.ref is not None
    sd_yaw = math.sqrt(fit.ref.cov[6, 6])
    assert sd_yaw == pytest.approx(cfg.prior_yaw_rad, rel=0.01)
    # 2 m/s of north velocity gained since the anchor: C_e = ∫a_n dt = 2 m/s
    _, sig_still = fit.ref.predict(1, 0.0, (b_int, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    _, sig_accel = fit.ref.predict(1, 0.0, (b_int, (0.0, 2.0, 0.0), (0.0, 0.0, 0.0)))
    assert sig_accel == pytest.approx(math.hypot(sig_still, 2.0 * cfg.prior_yaw_rad), rel=0.05)


@pytest.mark.parametrize("lag_s", [0.0, 0.1, 0.15, 0.2])
def test_the_fit_learns_a_late_measurement(lag_s: float) -> None:
    """A velocity that arrives ``lag_s`` late (a GPS through a filter): y(t) = v(t − d) with
    v = 2 sin(2π·0.25 t) m/s on north, level flight. The fit's lag column (−L, the IMU's
    mean acceleration over the last LAG_WINDOW_S) recovers d. Tolerance 0.01 s: the
    first-order model y ≈ v − d·L leaves second-order terms (d²ȧ/2; L lags a by
    LAG_WINDOW_S/2) that V0 and b absorb in part; computed: ≤ 0.001 s at this 0.25 Hz,
    0.006 s at 0.5 Hz, so 0.01 s fails only on a wrong column or sign."""
    fit = ReferenceFit(FdiConfig())
    w = 2.0 * math.pi * 0.25

    def v(t: float) -> float:
        return 2.0 * math.sin(w * t)

    for k in range(100):  # 4 s at 25 Hz, three axes
        t = 1.0 + k / 25.0
        a_int = v(t) - v(0.0)  # A_n = ∫ a_n dt
        l_n = (v(t) - v(t - LAG_WINDOW_S)) / LAG_WINDOW_S
        b_int = tuple((np.eye(3) * t).ravel().tolist())
        for j in range(3):
            z = v(t - lag_s) - a_int if j == 0 else 0.0
            fit.add(t, j, z, (b_int, (0.0, a_int, 0.0), (l_n, 0.0, 0.0)), 0.03)
    fit.prune_and_fit(5.0)
    assert fit.ref is not None
    assert fit.ref.theta[LAG] == pytest.approx(lag_s, abs=0.01)
    # an observed lag (> 2σ) for every lag but zero: the compensation applies it
    assert (fit.ref.observed(LAG) > 0.0) == (lag_s > 0.0)


def test_dead_reckoning_sigma_grows_as_documented() -> None:
    # σ(t) = √(σ0² + (σ_b t)² + q t) with the defaults σ0 = 0.03 m/s, σ_b = 0.03 m/s²,
    # √q = 4e-3 m/s^1.5: at 10 s, √(9e-4 + 0.09 + 1.6e-4) = 0.30176 m/s
    cfg = FdiConfig()
    assert sigma_dead_reckoning_mps(cfg, 0.0) == pytest.approx(0.03, rel=1e-12)
    assert sigma_dead_reckoning_mps(cfg, -1.0) == pytest.approx(0.03, rel=1e-12)  # clamped
    assert sigma_dead_reckoning_mps(cfg, 10.0) == pytest.approx(math.sqrt(0.09106), rel=1e-12)


def test_dead_reckoning_age_is_the_inverse_of_its_sigma() -> None:
    """A takeover restarts a dead reckoning from the σ the old owner published: the age
    found from it gives that σ back (to float round-off), 0 at or below σ0."""
    cfg = FdiConfig()
    for age_s in (0.0, 0.5, 3.0, 10.0, 60.0):
        sigma = sigma_dead_reckoning_mps(cfg, age_s)
        assert dead_reckoning_age_s(cfg, sigma) == pytest.approx(age_s, abs=1e-9)
    assert dead_reckoning_age_s(cfg, 0.01) == 0.0


def test_fit_rows_array_kept_between_fits_equals_the_rows_converted_afresh() -> None:
    """ReferenceFit keeps its rows as an array between fits (each row converted once): after
    rows added, pruned and dropped in any order they equal the rows converted at once,
    bit for bit, and so does the fit."""
    rng = np.random.default_rng(7)
    fit, ref = ReferenceFit(FdiConfig()), ReferenceFit(FdiConfig())
    t = 0.0
    for step in range(600):
        t += 0.033
        axis = int(rng.integers(3))
        ints = (
            tuple(rng.normal(size=9).tolist()),
            tuple(rng.normal(size=3).tolist()),
            tuple(rng.normal(size=3).tolist()),
        )
        z, sigma = float(rng.normal()), float(rng.uniform(0.05, 0.3))
        for f in (fit, ref):
            f.add(t, axis, z, ints, sigma)
        if step == 300:
            for f in (fit, ref):
                f.drop_before(t - 2.0)
        ref._rows_array = None  # the reference converts every row at every fit
        for f in (fit, ref):
            f.prune_and_fit(t)
        assert fit._n_added - fit._n_dropped == len(fit.rows)
        if step % 7 == 0:  # what the next fit would use, against the rows as they are
            rows = list(fit.rows)
            n = len(rows)
            axes = np.array([r[1] for r in rows])
            x0 = np.zeros((n, 8))  # V0's indicator, −B_j, C_j, −L_j of each row's axis j
            x0[np.arange(n), axes] = 1.0
            x0[:, 3:6] = -np.array([r[3] for r in rows]).reshape(n, 3, 3)[np.arange(n), axes]
            x0[:, 6] = np.array([r[4] for r in rows])[np.arange(n), axes]
            x0[:, 7] = -np.array([r[6] for r in rows])[np.arange(n), axes]
            afresh = np.column_stack(
                (
                    axes,
                    np.array([r[2] for r in rows]),
                    np.array([1.0 / r[5] ** 2 for r in rows]) / FdiConfig().correlation_samples,
                    x0,
                )
            )
            assert np.array_equal(fit._array(), afresh)
        if fit.ref is not None:
            assert ref.ref is not None
            assert fit.ref.theta == ref.ref.theta
            assert np.array_equal(fit.ref.cov, ref.ref.cov)
    assert fit.fitted and len(fit.rows) > 100
