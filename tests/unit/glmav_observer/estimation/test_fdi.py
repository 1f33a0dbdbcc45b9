"""The FDI's pieces on constructed data: the change classifier, the reference fit."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from glmav_observer.estimation.fdi import (
    LAG,
    LAG_WINDOW_S,
    MIN_PRE_SAMPLES,
    RAMP_LIMIT_MPS2,
    RAMP_WINDOW_S,
    AxisMonitor,
    FdiConfig,
    ReferenceFit,
    classify_change,
    dead_reckoning_age_s,
    sigma_dead_reckoning_mps,
)
from glmav_observer.records import FaultEvent

SIG = (0.03, 0.03, 0.03)
RATE_HZ = 25.0


def _recent(
    *,
    axis_step: int | None = None,
    step_mps: float = 0.0,
    ramp_mps2: float = 0.0,
    accel_db: tuple[float, float, float] | None = None,
    yaw_rad: float = 0.7,
    seed: int = 0,
) -> list[tuple[float, int, float, tuple[float, ...]]]:
    """1.5 s of residuals of the three axes at 25 Hz, a change at t = 1.0 s.

    B(t) = ∫E dt for a level vehicle at heading ``yaw_rad``: a body-x accelerometer change
    shows on n and e as ramps of Δb·cos ψ and Δb·sin ψ.
    """
    rng = np.random.default_rng(seed)
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    E = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = []
    for k in range(int(1.5 * RATE_HZ)):
        t = k / RATE_HZ
        B = E * t
        for j in range(3):
            r = float(rng.normal(0.0, SIG[j]))
            if t >= 1.0:
                if axis_step == j:
                    r += step_mps + ramp_mps2 * (t - 1.0)
                if accel_db is not None:
                    r -= float((B[j] - E[j] * 1.0) @ np.asarray(accel_db))
            out.append((t, j, r, tuple(B.ravel().tolist())))
    return out


def test_a_velocity_step_is_a_velocity_step() -> None:
    kind, _, t_c = classify_change(0, _recent(axis_step=0, step_mps=0.5), SIG)
    assert kind == "velocity"
    assert abs(t_c - 1.0) <= 1.0 / RATE_HZ + 1e-9  # the first sample of the step


def test_an_accelerometer_step_is_blamed_on_the_accelerometer() -> None:
    kind, db, t_c = classify_change(0, _recent(accel_db=(0.8, 0.0, 0.0)), SIG)
    assert kind == "accel"
    # Δb recovered to the noise of 0.5 s of 25 Hz residuals (σ 0.03 m/s): within 0.25 m/s²
    assert abs(db[0] - 0.8) <= 0.25 and abs(db[1]) <= 0.25, db
    assert abs(t_c - 1.0) <= 0.2


def test_an_offset_over_the_whole_window_is_the_reference_not_a_step() -> None:
    rec = [(t, j, r + (0.3 if j == 1 else 0.0), b) for t, j, r, b in _recent()]
    kind, _, _ = classify_change(1, rec, SIG)
    assert kind == "offset"


def test_a_step_through_an_autopilots_filter_is_still_a_velocity_step() -> None:
    """A 0.5 m/s step passed through a 0.2 s first-order low-pass (an EKF's output)."""
    rec = [
        (t, j, r + (0.5 * (1 - math.exp(-(t - 1.0) / 0.2)) if j == 2 and t >= 1.0 else 0.0), b)
        for t, j, r, b in _recent()
    ]
    kind, _, t_c = classify_change(2, rec, SIG)
    assert kind == "velocity"
    assert abs(t_c - 1.0) <= 0.1


def test_no_history_before_the_change_is_undecided() -> None:
    rec = [r for r in _recent(axis_step=0, step_mps=0.5) if r[0] >= 1.25]  # armed after the step
    assert len([r for r in rec if r[1] == 0]) - MIN_PRE_SAMPLES < 3
    kind, _, _ = classify_change(0, rec, SIG)
    assert kind == "undecided"


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


def _isolated_axis(residual: Callable[[float], float], rate_hz: float = 10.0) -> AxisMonitor:
    """An axis isolated (bias) at t = 0 whose residual against the dead reckoning then
    follows ``residual`` over RAMP_WINDOW_S, at ``rate_hz``, with 0.05 m/s of noise."""
    cfg = FdiConfig()
    ax = AxisMonitor("n", 0, cfg, ReferenceFit(cfg))
    ax.fault = FaultEvent("n", "bias", 0.0)
    rng = np.random.default_rng(3)
    n = round(RAMP_WINDOW_S * rate_hz) + 1
    for k in range(n):
        t = k / rate_hz
        ax._ramp.append((t, residual(t) + float(rng.normal(0.0, 0.05))))
    return ax


def test_a_residual_that_ramps_after_an_isolation_is_the_imus_path() -> None:
    """A lost attitude: g·δθ ≈ 1 m/s² on n (a 6° tilt). Over 1 s at 10 Hz with σ 0.05 the
    slope's σ is 0.05/√(Σ(t − t̄)²) = 0.05/0.96 ≈ 0.05 m/s²: 1 m/s² is far beyond 0.5 + 3σ;
    0.3 m/s² (an accelerometer bias the fit can leave) is below it."""
    assert _isolated_axis(lambda t: 0.5 + 1.0 * t).ramping(RAMP_WINDOW_S)
    assert not _isolated_axis(lambda t: 0.5 + 0.3 * t).ramping(RAMP_WINDOW_S)
    assert RAMP_LIMIT_MPS2 == 0.5  # the numbers above assume it


def test_a_bias_that_ends_is_a_step_not_a_ramp() -> None:
    """A 1 m/s bias removed mid-window: a line through it has slope ≈ 1.5 m/s² (it
    withdrew 26 injected isolations at their end before the step model was compared);
    the single-step fit explains it better."""
    assert not _isolated_axis(lambda t: 1.0 if t < 0.5 else 0.0).ramping(RAMP_WINDOW_S)
    assert not _isolated_axis(lambda t: 0.0 if t < 0.5 else 1.0).ramping(RAMP_WINDOW_S)


def test_a_noisy_measurement_is_not_withdrawn_on_a_chance_ramp() -> None:
    """A noise fault (σ 0.5 m/s at 10 Hz) can draw a steep line over 1 s by chance; the
    measurement's own second differences are then far above their healthy level
    (6σ² = 1.5 against 6 · 0.05² = 0.015), and a noisy measurement is never the IMU's
    ramp."""
    ax = _isolated_axis(lambda t: 0.5 + 1.0 * t)
    assert ax.ramping(RAMP_WINDOW_S)  # smooth (no second differences recorded yet)
    ax._d2y_sq.extend([1.5] * len(ax._ramp))
    assert not ax.ramping(RAMP_WINDOW_S)


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
