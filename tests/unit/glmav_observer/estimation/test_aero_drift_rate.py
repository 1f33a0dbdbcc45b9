"""The dead reckoning's drift measured while healthy (estimation/aero/drift_rate.py), its
use for the lost axis's published σ (aero/aided.py), and the drag model's held-out-in-time
validation (aero/model.py, ``holdout_s``); issue 32."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from glmav_observer.estimation.aero import AidedAxis, AidedAxisConfig, DragModel, DragModelConfig
from glmav_observer.estimation.aero.drift_rate import DriftRate, DriftRateConfig, body_bias_fit
from glmav_observer.estimation.aiding import LostAxisAiding
from glmav_observer.frames import e_exact

F = NDArray[np.float64]
RATE_HZ = 10.0


def _integrals(t_s: F, bias_body_mps2: F, drift_ned_mps2: F | None = None) -> tuple[F, F, F]:
    """(A (n, 3), B (n, 9), v (n, 3)) of a turning vehicle whose accelerometer has a
    constant body-frame bias and, optionally, an earth-frame acceleration error that
    changes (``drift_ned_mps2`` (n, 3): the error at each sample). v is exact: the
    measurement the statistic compares with."""
    dt = 1.0 / RATE_HZ
    euler = np.column_stack((0.05 * np.sin(0.2 * t_s), 0.05 * np.cos(0.3 * t_s), 0.1 * t_s))
    E = e_exact(euler)
    v = np.column_stack((2.0 * np.sin(0.1 * t_s), 1.5 * np.cos(0.08 * t_s), 0.0 * t_s))
    a_true = np.gradient(v, dt, axis=0)
    err = np.einsum("nij,j->ni", E, bias_body_mps2)
    if drift_ned_mps2 is not None:
        err = err + drift_ned_mps2
    A = np.cumsum((a_true + err) * dt, axis=0)
    B = np.cumsum(E.reshape(-1, 9) * dt, axis=0)
    # A's first step: integrate from the first sample (v's change then starts at 0)
    A = A - A[0] + v[0]
    return A, B, v


def _rate(t_s: F, A: F, B: F, v: F, config: DriftRateConfig | None = None) -> DriftRate:
    d = DriftRate(config)
    for i in range(len(t_s)):
        d.observe(float(t_s[i]), A[i], B[i], v[i])
    return d


def test_body_bias_fit_recovers_a_bias_on_a_turning_vehicle() -> None:
    t = np.arange(0.0, 16.0, 1.0 / RATE_HZ)
    b = np.array([0.2, -0.1, 0.05])
    A, B, v = _integrals(t, b)
    idx = np.arange(0, len(t), int(RATE_HZ))  # 1 s rows, as the statistic and the benchmark
    b_hat = body_bias_fit(
        np.diff(B[idx], axis=0).reshape(-1, 3, 3),
        np.diff(A[idx] - v[idx], axis=0),
        sigma_v_mps=0.1,
        prior_mps2=0.5,
    )
    # exact data: only the prior pulls b̂ (weight 1/0.5² against 15 rows of 1/(2·0.1²)
    # per s² of ∫E dt: a shrink of ~4e-3 relative, 1e-3 m/s² on 0.2)
    assert b_hat == pytest.approx(b, abs=2e-3)


def test_a_constant_body_bias_is_not_drift() -> None:
    """The statistic fits the bias first, as the estimator does: a constant body bias on a
    turning vehicle leaves (nearly) no drift."""
    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    A, B, v = _integrals(t, np.array([0.3, -0.2, 0.1]))
    rate = _rate(t, A, B, v).rate_mps2()
    assert rate is not None
    # exact data: what is left is the fit's prior shrink (~1e-3 m/s², above) at most
    assert max(rate) < 5e-3


def test_a_changing_acceleration_error_is_measured() -> None:
    """An earth-frame error that steps by 0.1 m/s² every 10 s (alternating sign): the
    dead reckoning started before a step is off by the step after it. Across lags the
    worst RMS error per second is of that size."""
    t = np.arange(0.0, 100.0, 1.0 / RATE_HZ)
    step = np.where((t // 10.0) % 2 == 0, 0.05, -0.05)
    drift = np.column_stack((step, 0.0 * t, 0.0 * t))
    A, B, v = _integrals(t, np.zeros(3), drift)
    rate = _rate(t, A, B, v).rate_mps2()
    assert rate is not None
    # n: a 0.1 m/s² step seen by a fit that averaged both levels: the RMS of the error
    # rate lies between a quarter of the step and the step (the fit window straddles a
    # step about half the time). e and d have none of their own: what they show is the
    # n error that the body-frame bias fit took for a bias, rotated by the heading's
    # 1 rad per 10 s; well below n's
    assert 0.025 < rate[0] < 0.1
    assert rate[1] < 0.5 * rate[0] and rate[2] < 0.5 * rate[0]


def test_no_statistic_before_enough_instants_and_after_a_restart() -> None:
    cfg = DriftRateConfig()
    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    A, B, v = _integrals(t, np.zeros(3))
    # fit window + shortest lag + (min_windows − 1) s of data: one instant short
    short = cfg.fit_window_s + cfg.lags_s[0] + cfg.min_windows - 1.5
    assert _rate(t[t < short], A[t < short], B[t < short], v[t < short]).rate_mps2() is None
    d = _rate(t, A, B, v)
    assert d.rate_mps2() is not None
    d.clear()
    assert d.rate_mps2() is None
    # time going back (a new boot) starts afresh too
    d = _rate(t, A, B, v)
    d.observe(1.0, A[10], B[10], v[10])
    assert d.rate_mps2() is None


def test_non_finite_samples_are_ignored() -> None:
    t = np.arange(0.0, 40.0, 1.0 / RATE_HZ)
    A, B, v = _integrals(t, np.zeros(3))
    d = _rate(t, A, B, v)
    before = d.rate_mps2()
    d.observe(40.5, (math.nan, 0.0, 0.0), B[-1], v[-1])
    assert d.rate_mps2() == before


def test_published_sigma_covers_the_measured_drift_and_the_estimate_is_unchanged() -> None:
    """A drift rate above the prior σ_b raises the published σ only; below it, or None,
    the filter is the prior's exactly."""
    cfg = AidedAxisConfig(accel_noise_mps2_rthz=0.05, accel_bias_h_mps2=0.05)
    plain = AidedAxis(0, 1.0, 0.1, 0.0, cfg)
    low = AidedAxis(0, 1.0, 0.1, 0.0, cfg, drift_rate_mps2=0.01)
    high = AidedAxis(0, 1.0, 0.1, 0.0, cfg, drift_rate_mps2=0.2)
    for ax in (plain, low, high):
        for _ in range(1000):
            ax.propagate(0.01, (0.2, 0.0, 0.0))
    # P = 0.1² + 0.05² · 10 + σ_b² · 10² (the module docstring's propagation)
    assert plain.state().sigma_mps == pytest.approx(math.sqrt(0.01 + 0.025 + 0.25))
    assert low.state().sigma_mps == plain.state().sigma_mps
    assert high.state().sigma_mps == pytest.approx(math.sqrt(0.01 + 0.025 + 4.0))
    # the filter's own variance (its gains and rules) is the prior's in all three
    assert high.P_mps2 == plain.P_mps2 == low.P_mps2
    assert high.v_mps == plain.v_mps


def test_published_sigma_after_an_update_is_the_joseph_form() -> None:
    from glmav_observer.estimation.aero import PseudoMeasurement

    cfg = AidedAxisConfig(accel_noise_mps2_rthz=0.05, accel_bias_h_mps2=0.05)
    plain = AidedAxis(0, 0.0, 0.1, 0.0, cfg)
    high = AidedAxis(0, 0.0, 0.1, 0.0, cfg, drift_rate_mps2=0.2)
    for ax in (plain, high):
        for _ in range(500):
            ax.propagate(0.01, (0.0, 0.0, 0.0))
    p_pub = high.P_pub_mps2
    P = plain.P_mps2
    pm = PseudoMeasurement(0.1, 0.3, 0.0)
    assert plain.update(pm) and high.update(pm)
    assert high.v_mps == plain.v_mps  # the same gain
    # the first update: Δt_u = corr_time_s, R = σ_z²; K from the prior's P
    R = 0.3**2
    K = P / (P + R)
    assert plain.P_mps2 == pytest.approx((1.0 - K) * P)
    assert high.state().sigma_mps == pytest.approx(math.sqrt((1 - K) ** 2 * p_pub + K * K * R))
    assert high.state().sigma_mps > plain.state().sigma_mps


def test_lost_axis_aiding_passes_the_measured_rate_and_restart_forgets_it() -> None:
    aiding = LostAxisAiding(0.1)
    t = np.arange(0.0, 60.0, 1.0 / RATE_HZ)
    step = np.where((t // 10.0) % 2 == 0, 0.25, -0.25)
    A, B, v = _integrals(t, np.zeros(3), np.column_stack((step, 0.0 * t, 0.0 * t)))
    e_flat = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    for i in range(len(t)):
        aiding.learn(
            float(t[i]),
            (0.0, 0.0, -9.8),
            e_flat,
            tuple(v[i]),
            a_int_ned_mps=A[i],
            b_int_flat_s=B[i],
        )
    rate = aiding.drift.rate_mps2()
    assert rate is not None and rate[0] > 0.05  # above the prior σ_b: it raises σ
    aiding.start(60.0, 0)
    assert aiding._axis is not None and aiding._axis.drift_rate_mps2 == rate[0]
    aiding.restart()
    assert aiding.lost_idx is None and aiding.drift.rate_mps2() is None


def _regime_flight(t_s: F, seed: int) -> tuple[F, F, F]:
    """(f_body, E, v) of a vehicle whose true drag is quadratic in the airspeed (wind 3 m/s
    north) while the model's law takes it in the ground speed (aero/model.py, A2): it
    fits at one speed and errs once the vehicle flies at another. It hovers, then flies
    north at 6 m/s from 60 s on, every 40 s, for 20 s."""
    rng = np.random.default_rng(seed)
    fast = ((t_s - 60.0) % 40.0 < 20.0) & (t_s >= 60.0)
    v_n = np.where(fast, 6.0, 0.4 * np.sin(0.5 * t_s))
    v = np.column_stack((v_n, 0.4 * np.cos(0.4 * t_s), 0.0 * t_s))
    euler = np.column_stack((0.02 * np.sin(0.3 * t_s), 0.02 * np.cos(0.2 * t_s), 0.3 * t_s))
    E = e_exact(euler)
    u = np.einsum("nji,nj->ni", E, v - np.array([3.0, 0.0, 0.0]))
    f = np.zeros_like(v)
    for j in range(2):
        f[:, j] = -0.3 * u[:, j] - 0.05 * u[:, j] * np.abs(u[:, j])
    f[:, :2] += rng.normal(0.0, 0.02, (len(t_s), 2))
    f[:, 2] = -9.81
    return f, E, v


def test_held_out_validation_sees_what_the_one_step_validation_does_not() -> None:
    """A model learnt on hovers is validated one step ahead on data like them; frozen for
    10-20 s it meets the fast legs it never saw: its held-out NEES is the larger."""
    t = np.arange(0.0, 200.0, 1.0 / RATE_HZ)
    f, E, v = _regime_flight(t, 0)
    model = DragModel(DragModelConfig(holdout_s=10.0))
    for i in range(len(t)):
        model.learn(float(t[i]), f[i], E[i], v[i])
    nees, held = model.nees, model.nees_held_out
    assert np.isfinite(held[:2]).all()
    assert (held[:2] > nees[:2]).all()


def test_holdout_off_is_the_model_without_it() -> None:
    t = np.arange(0.0, 150.0, 1.0 / RATE_HZ)
    f, E, v = _regime_flight(t, 1)
    on = DragModel(DragModelConfig(holdout_s=10.0))
    off = DragModel(DragModelConfig(holdout_s=0.0))
    for i in range(len(t)):
        on.learn(float(t[i]), f[i], E[i], v[i])
        off.learn(float(t[i]), f[i], E[i], v[i])
    # learning is the same (the held-out copies only validate); the validation differs
    assert np.array_equal(on.theta, off.theta)
    assert np.array_equal(on.nees, off.nees, equal_nan=True)
    assert np.isnan(off.nees_held_out).all()
    # a frozen copy does not move with the model's later learning
    frozen = on._frozen()
    th = frozen.theta.copy()
    on.learn(150.0, f[-1] + 1.0, E[-1], v[-1])
    assert np.array_equal(frozen.theta, th)
