"""The drag model, its pseudo-measurement and the aided axis on synthetic flights.

The synthetic vehicle: a turning flight (heading rotating at 0.2 rad/s, so the body axes
see every earth direction and the constant c separates from the wind), small roll/pitch,
NED velocity of a few m/s, and an accelerometer reading (A2) in body axes
f_j = c_j − k_j u_j − q_j s_j|s_j| (u = Eᵀ(v − w), s = Eᵀv) plus white noise σ_f, at 25 Hz.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from glmav_observer.estimation.aero import (
    AidedAxis,
    AidedAxisConfig,
    DragModel,
    DragModelConfig,
    PseudoMeasurement,
)
from glmav_observer.frames import e_exact

F = NDArray[np.float64]
RATE_HZ = 25.0
SIGMA_F = 0.05  # m/s², accelerometer noise averaged over one 40 ms interval


def flight(
    t_s: F,
    *,
    k: tuple[float, float] = (0.40, 0.35),
    c: tuple[float, float] = (0.10, -0.05),
    q: tuple[float, float] = (0.0, 0.0),
    wind_ne: tuple[float, float] = (2.0, -1.0),
    sigma_f: float = SIGMA_F,
    seed: int = 0,
) -> tuple[F, F, F, F]:
    """(f_body (n,3), E (n,3,3), v_ned (n,3), a_ned (n,3) = dv/dt) of the synthetic flight."""
    rng = np.random.default_rng(seed)
    euler = np.column_stack((0.10 * np.sin(0.3 * t_s), -0.10 * np.cos(0.25 * t_s), 0.2 * t_s))
    v = np.column_stack(
        (3.0 * np.sin(0.11 * t_s), 2.5 * np.cos(0.07 * t_s), 0.5 * np.sin(0.05 * t_s))
    )
    a = np.column_stack(
        (0.33 * np.cos(0.11 * t_s), -0.175 * np.sin(0.07 * t_s), 0.025 * np.cos(0.05 * t_s))
    )
    E = e_exact(euler)
    w = np.array([wind_ne[0], wind_ne[1], 0.0])
    u = np.einsum("nji,nj->ni", E, v - w)  # Eᵀ(v − w)
    s = np.einsum("nji,nj->ni", E, v)
    f = np.zeros_like(v)
    for j in range(2):
        f[:, j] = c[j] - k[j] * u[:, j] - q[j] * s[:, j] * np.abs(s[:, j])
    f[:, :2] += rng.normal(0.0, sigma_f, (len(t_s), 2))
    f[:, 2] = -9.81
    return f, E, v, a


def learnt(
    t_end_s: float = 120.0, config: DragModelConfig | None = None, **kw: object
) -> DragModel:
    model = DragModel(config)
    t = np.arange(0.0, t_end_s, 1.0 / RATE_HZ)
    f, E, v, _ = flight(t, **kw)  # type: ignore[arg-type]
    for i in range(len(t)):
        model.learn(float(t[i]), f[i], E[i], v[i])
    return model


def test_recovers_drag_bias_and_wind() -> None:
    model = learnt()
    th = model.theta
    sd = np.sqrt(np.diagonal(model.cov_theta, axis1=1, axis2=2))
    k, c, w = (0.40, 0.35), (0.10, -0.05), (2.0, -1.0)
    truth = np.array([[c[j], k[j], k[j] * w[0], k[j] * w[1], 0.0] for j in range(2)])
    # least squares with a Gaussian residual: each parameter within 4.5 of its own σ
    # (P(|z| > 4.5) = 7e-6 per parameter; 10 parameters)
    assert np.all(np.abs(th - truth) <= 4.5 * sd), (th, truth, sd)
    # and those σ are small enough to mean something: ~2250 effective samples at σ_f 0.05
    # over a few m/s of speed spread give σ(k) ≈ 0.05 / (2 √2250) ≈ 1e-3; 0.01 is 10×
    assert sd[:, 1].max() < 0.01
    wind = model.wind_ne_mps()
    assert wind is not None
    # the wind from k·w / k: σ(w) ≈ σ(kw)/k ≈ 0.02 m/s; 0.1 m/s is ≥ 4σ
    assert abs(wind[0] - 2.0) < 0.1 and abs(wind[1] + 1.0) < 0.1
    # residual spread: ~2250 effective samples, relative σ of a σ estimate 1/√(2n) ≈ 1.5 %
    assert model.sigma_f_mps2 == pytest.approx([SIGMA_F, SIGMA_F], rel=0.1)
    assert model.trust().ok, model.trust().reason


def test_recovers_quadratic_drag() -> None:
    model = learnt(q=(0.04, 0.03), wind_ne=(0.0, 0.0))
    sd = np.sqrt(np.diagonal(model.cov_theta, axis1=1, axis2=2))
    # the same 4.5σ bound on the linear and the quadratic coefficient of each axis
    assert abs(model.k_per_s[0] - 0.40) <= 4.5 * sd[0, 1]
    assert abs(model.q_per_m[0] - 0.04) <= 4.5 * sd[0, 4]
    assert abs(model.q_per_m[1] - 0.03) <= 4.5 * sd[1, 4]


def test_untrusted_without_data_or_without_drag() -> None:
    fresh = DragModel()
    assert not fresh.trust().ok
    E = e_exact(np.array([0.1, -0.1, 0.5]))
    assert fresh.pseudo_measurement(np.array([0.0, 0.0, -9.81]), E, np.zeros(3), 0) is None
    # an accelerometer that does not feel the airspeed (k = 0): k is not clearly > 0
    no_drag = learnt(60.0, k=(0.0, 0.0))
    tr = no_drag.trust()
    assert not tr.ok and "not clearly > 0" in tr.reason


def test_a_row_whose_k_is_clearly_negative_refuses_the_model() -> None:
    # the y row's force grows *with* the speed along it (k_y = −0.3 1/s): no drag does
    # that (drag dissipates), so the law does not hold where this vehicle flies; its x row
    # fits, yet shares the vehicle, the wind and the attitude
    model = learnt(k=(0.40, -0.30))
    sd_k = math.sqrt(model.cov_theta[1, 1, 1])
    # the data say so clearly: k_y within 4.5σ of −0.3 and σ ≈ 1e-3 (as above)
    assert model.k_per_s[1] <= -5.0 * sd_k, (model.k_per_s, sd_k)
    tr = model.trust()
    assert not tr.ok and "y: k" in tr.reason and "clearly < 0" in tr.reason, tr
    t = np.arange(120.0, 121.0, 1.0 / RATE_HZ)
    f, E, v, _ = flight(t, k=(0.40, -0.30), seed=3)
    assert model.pseudo_measurement(f[0], E[0], v[0], 0) is None
    # the validation's pseudo-measurements go on (they only measure, and the x row's are
    # right): when the rows fit again the model needs no new validation
    assert model.pseudo_measurement(f[0], E[0], v[0], 0, validated=False) is not None
    # refuse_negative_k off: the model as before, the x row alone aids
    before = learnt(k=(0.40, -0.30), config=DragModelConfig(refuse_negative_k=False))
    assert before.trust().ok and before.trust().reason.startswith("y: k")
    pm = before.pseudo_measurement(f[0], E[0], v[0], 0)
    # from the x row, exact law plus noise σ_f: within 5σ of the truth
    assert pm is not None and abs(pm.v_mps - v[0, 0]) <= 5.0 * pm.sigma_mps, (pm, v[0])


def test_hovering_is_not_enough_excitation() -> None:
    model = DragModel()
    E = e_exact(np.array([0.0, 0.0, 0.3]))
    rng = np.random.default_rng(1)
    for i in range(1500):
        v = rng.normal(0.0, 0.05, 3)  # hover: 5 cm/s of jitter
        f = np.array([-0.4 * v[0], -0.4 * v[1], -9.81]) + rng.normal(0.0, 0.05, 3)
        model.learn(i / RATE_HZ, f, E, v)
    tr = model.trust()
    assert not tr.ok and "speed spread" in tr.reason


def f_true(E: F, v: F) -> F:
    """The noiseless accelerometer of :func:`flight`'s default vehicle (linear, wind)."""
    u = E.T @ (v - np.array([2.0, -1.0, 0.0]))
    return np.array([0.10 - 0.40 * u[0], -0.05 - 0.35 * u[1], -9.81])


def test_d_is_not_observable_from_a_level_attitude() -> None:
    model = learnt(config=DragModelConfig(aided_axes=(0, 1, 2)))
    E_level = e_exact(np.array([0.0, 0.0, 1.0]))
    v = np.array([1.0, 2.0, 0.0])
    f = f_true(E_level, v)
    # |r_x,d| = |sin θ| = 0 and |r_y,d| = |sin φ cos θ| = 0 < row_min
    assert model.pseudo_measurement(f, E_level, v, 2) is None
    # n is observable at the same attitude (r_x,n = cos ψ, r_y,n = −sin ψ)
    assert model.pseudo_measurement(f, E_level, v, 0) is not None
    # and by default d is never aided (aided_axes = (0, 1))
    default = learnt()
    E_tilted = e_exact(np.array([0.3, -0.3, 1.0]))
    assert default.pseudo_measurement(f_true(E_tilted, v), E_tilted, v, 2) is None
    # with d allowed, d is geometrically visible at that tilt (|r_x,d| = sin 0.3 ≈ 0.3 ≥
    # row_min) and the equations give a value within its σ...
    pm = model.pseudo_measurement(f_true(E_tilted, v), E_tilted, v, 2, validated=False)
    assert pm is not None and abs(pm.v_mps) < 4.0 * pm.sigma_mps
    # ...but it is refused: this flight never tilted beyond 0.1 rad < row_min, so d was
    # never validated against its measurement while healthy
    assert model.nees[2] != model.nees[2]  # NaN: no validation of d
    assert model.pseudo_measurement(f_true(E_tilted, v), E_tilted, v, 2) is None


def test_pseudo_measurement_accuracy_and_sigma() -> None:
    model = learnt()
    t = np.arange(120.0, 140.0, 1.0 / RATE_HZ)
    f, E, v, _ = flight(t, seed=7)
    z: list[float] = []
    sig: list[float] = []
    for axis in (0, 1):
        for i in range(0, len(t), 2):
            pm = model.pseudo_measurement(f[i], E[i], v[i], axis, sigma_v_known_mps=0.0)
            if pm is None:
                continue
            z.append((pm.v_mps - v[i, axis]) / pm.sigma_mps)
            sig.append(pm.sigma_mps)
    zz = np.asarray(z)
    assert len(zz) > 400  # both axes observable most of the time while turning
    # σ ≈ σ_f / (k |r_L|) combined over two rows: 0.05/0.4 = 0.125 at |r| = 1; ≤ 0.3 always
    assert max(sig) < 0.3
    # the errors are Gaussian with that σ: mean z² within ±0.3 of 1 (σ of the mean of
    # ~500 z² is √(2/500) = 0.06, so ±0.3 is 5σ) and no |z| above 4.5 (7e-6 each)
    assert 0.7 < float(np.mean(zz**2)) < 1.3
    assert np.abs(zz).max() < 4.5


def _run_loss(
    model: DragModel,
    *,
    axis: int,
    accel_bias_mps2: float,
    t0_s: float = 120.0,
    horizon_s: float = 60.0,
    wind_step: tuple[float, tuple[float, float]] | None = None,
    glitch: tuple[float, float, int, float] | None = None,
    check_measured: bool = True,
    **kw: object,
) -> tuple[F, F, F, F, AidedAxis]:
    """Lose ``axis`` at t0: (times, |aided error|, |DR error|, aided σ, the filter), 25 Hz.

    ``wind_step`` (after s, new (w_n, w_e)): the wind changes during the loss.
    ``glitch`` (from s, to s, NED axis, m/s): that measured axis is off by that much in
    between (the IMU is not). ``check_measured``: the measured axes go to
    :meth:`AidedAxis.update` (rule 1)."""
    t = np.arange(t0_s, t0_s + horizon_s, 1.0 / RATE_HZ)
    f, E, v, _ = flight(t, seed=3, **kw)  # type: ignore[arg-type]
    if wind_step is not None:
        f_new, _, _, _ = flight(t, seed=3, wind_ne=wind_step[1], **kw)  # type: ignore[arg-type]
        after = t - t0_s >= wind_step[0]
        f[after] = f_new[after]
    v_meas = v.copy()
    if glitch is not None:
        on = (t - t0_s >= glitch[0]) & (t - t0_s < glitch[1])
        v_meas[on, glitch[2]] += glitch[3]
    ai = AidedAxis(axis, float(v[0, axis]), 0.1, float(t[0]))
    dr = AidedAxis(axis, float(v[0, axis]), 0.1, float(t[0]))
    e_ai, e_dr, s_ai = [], [], []
    for i in range(1, len(t)):
        dt = float(t[i] - t[i - 1])
        # the IMU's earth-frame acceleration: exact mean over the interval plus the bias
        a_mean = (v[i] - v[i - 1]) / dt + accel_bias_mps2
        ai.propagate(dt, a_mean)
        dr.propagate(dt, a_mean)
        if check_measured:
            ai.update_from_model(model, f[i], E[i], v_meas[i])
        else:
            pm = model.pseudo_measurement(f[i], E[i], v_meas[i], axis)
            ai.update(pm, model_broken=model.broken)
        e_ai.append(abs(ai.v_mps - v[i, axis]))
        e_dr.append(abs(dr.v_mps - v[i, axis]))
        s_ai.append(ai.state().sigma_mps)
    return t[1:] - t0_s, np.asarray(e_ai), np.asarray(e_dr), np.asarray(s_ai), ai


def test_aided_axis_bounded_where_dead_reckoning_drifts() -> None:
    model = learnt()
    for axis in (0, 1):
        # an accelerometer bias of 0.04 m/s² left uncompensated: 0.8 σ_b of the noise model
        # (AidedAxisConfig.accel_bias_h_mps2 = 0.05), inside what rule 2 tolerates
        tt, e_ai, e_dr, sigma, ai = _run_loss(model, axis=axis, accel_bias_mps2=0.04)
        # dead reckoning: 0.04 · 60 = 2.4 m/s after a minute
        assert e_dr[-1] == pytest.approx(2.4, abs=0.05)
        # aided: the pseudo-measurement (σ ≈ 0.1 m/s) holds the axis; issue 13's bounds
        # 10 s (0.2 worst) and 60 s (0.3) with the filter's lag to the bias (the 1-state
        # filter lags the bias by ≈ b Δt / K, shrinking as K grows with the time since
        # the hand-over)
        assert e_ai[tt >= 10.0].max() < 0.2
        assert e_ai[-1] < 0.3
        st = ai.state()
        assert st.aided and ai.n_rejected == 0 and not ai.stopped, st
        # σ covers the error (issue 13: 95 % of the time within 2σ)
        assert np.mean(e_ai <= 2.0 * sigma) >= 0.95


def test_a_bias_beyond_the_noise_model_falls_back_to_dead_reckoning() -> None:
    """Rule 2's price: with 0.1 m/s² (2 σ_b) the dead reckoning leaves its own σ (z² → 4)
    and the rule cannot tell it from a stale model; the axis falls back to dead reckoning,
    which it then equals (never worse, but the aiding's benefit is lost)."""
    model = learnt()
    _, e_ai, e_dr, _, ai = _run_loss(model, axis=0, accel_bias_mps2=0.1)
    assert ai.stopped and "dead reckoning" in ai.stop_reason
    assert e_ai[-1] == pytest.approx(e_dr[-1], abs=1e-9)


def test_wrong_model_is_gated_and_never_worse_than_dead_reckoning() -> None:
    model = learnt()
    # the vehicle changed (a payload, another airframe): its drag doubled after learning
    _, e_ai, e_dr, _, ai = _run_loss(model, axis=0, accel_bias_mps2=0.02, k=(0.8, 0.7))
    # the pseudo-measurement drifts off with the airspeed (by u·Δk/k): the two body rows
    # stop agreeing, the model declares itself broken and the axis falls back to dead
    # reckoning from the hand-over
    assert ai.stopped and ai.n_accepted < 50
    assert ai.v_mps == ai.v_dr_mps
    # never worse than dead reckoning, but for the updates accepted before the detection
    # (≤ 50 at 25 Hz, at the hand-over's low airspeed |u| < 0.5 m/s, so off by < 0.5 m/s
    # and weighted K < 0.2: < 0.1 m/s; measured 0.045)
    assert np.all(e_ai <= e_dr + 0.1)
    assert e_ai[-1] == pytest.approx(e_dr[-1], abs=1e-9)


def test_aided_axis_propagation_variance() -> None:
    cfg = AidedAxisConfig(accel_noise_mps2_rthz=0.05, accel_bias_h_mps2=0.05)
    ax = AidedAxis(0, 1.0, 0.1, 0.0, cfg)
    for _ in range(1000):
        ax.propagate(0.01, (0.2, 0.0, 0.0))
    # v = 1 + 0.2 · 10; P = 0.1² + 0.05² · 10 + 0.05² · 10² (module docstring)
    assert ax.v_mps == pytest.approx(3.0)
    assert ax.state().sigma_mps == pytest.approx(math.sqrt(0.01 + 0.025 + 0.25))
    assert not ax.state().aided


def test_gate_rejects_an_outlier_and_accepts_a_consistent_value() -> None:
    ax = AidedAxis(1, 0.0, 0.1, 0.0)
    ax.propagate(0.04, (0.0, 0.0, 0.0))
    assert not ax.update(PseudoMeasurement(5.0, 0.1, 0.0))  # 5 m/s ≫ 5 · √(0.1² + 0.1²)
    assert ax.v_mps == 0.0
    assert ax.update(PseudoMeasurement(0.1, 0.1, 0.0))
    assert 0.0 < ax.v_mps < 0.1


def test_bad_input() -> None:
    model = learnt(30.0)
    n = model.n_learned
    E = e_exact(np.array([0.0, 0.0, 0.0]))
    model.learn(31.0, np.array([math.nan, 0.0, -9.8]), E, np.zeros(3))  # ignored
    assert model.n_learned == n
    with pytest.raises(ValueError, match="lost_axis"):
        model.pseudo_measurement(np.zeros(3), E, np.zeros(3), 3)
    with pytest.raises(ValueError, match="lost_axis"):
        AidedAxis(5, 0.0, 0.1)


def test_rejections_in_a_row_fall_back_to_dead_reckoning() -> None:
    ax = AidedAxis(0, 0.0, 0.1, 0.0, AidedAxisConfig(max_rejections=5))
    ax.propagate(0.04, (1.0, 0.0, 0.0))
    assert ax.update(PseudoMeasurement(0.05, 0.05, 0.0))  # pulls v off the dead reckoning
    assert ax.v_mps != ax.v_dr_mps
    for _ in range(5):
        ax.propagate(0.04, (1.0, 0.0, 0.0))
        assert not ax.update(PseudoMeasurement(-10.0, 0.05, 0.0))
    # five rejections in a row: stopped, back on the dead reckoning (v0 + Σ a·dt)
    assert ax.stopped and not ax.state().aided
    assert ax.v_mps == pytest.approx(0.24)
    assert ax.v_mps == ax.v_dr_mps
    assert not ax.update(PseudoMeasurement(0.24, 0.05, 0.0))  # stopped for good


def test_a_glitch_in_a_measured_axis_is_not_followed() -> None:
    """Rule 1: e jumps by 2 m/s for 5 s while n is lost; the IMU says it did not."""
    model = learnt()
    glitch = (20.0, 25.0, 1, 2.0)
    tt, e_ai, e_dr, _, ai = _run_loss(model, axis=0, accel_bias_mps2=0.02, glitch=glitch)
    during = (tt >= 20.0) & (tt < 26.0)  # the glitch and the 1 s hold-off after it
    # nothing is made of the measurement while it lasts: 125 updates at 25 Hz in the
    # glitch, up to 25 more in the hold-off (measured 149)
    assert 125 <= ai.n_meas_suspect <= 150
    # the axis dead-reckons from where it was: the error moves by at most the bias times
    # the 6 s (0.02 · 6 = 0.12 m/s), not by the glitch (2 m/s · |r_e/r_n| ≈ 2 m/s)
    e_start = e_ai[int(np.argmax(during)) - 1]
    assert e_ai[during].max() <= e_start + 0.02 * 6.0 + 1e-9
    # aiding resumes after it and is not stopped: at 60 s the aided error is the
    # pseudo-measurement's (σ ≈ 0.1 m/s; measured 0.015), dead reckoning's 0.02 · 60 = 1.2
    assert ai.state().aided and not ai.stopped
    assert e_ai[-1] < 0.3 and e_dr[-1] == pytest.approx(1.2, abs=0.01)
    # without rule 1 the glitched pseudo-measurements reach the model: the two rows
    # disagree, the model is marked broken and the aiding is lost for the whole loss
    _, e_blind, _, _, blind = _run_loss(
        learnt(), axis=0, accel_bias_mps2=0.02, glitch=glitch, check_measured=False
    )
    assert blind.stopped and "two rows disagree" in blind.stop_reason
    assert e_blind[-1] == pytest.approx(e_dr[-1], abs=1e-9)


@pytest.mark.parametrize("w_n_after", [3.0, 2.3])
def test_a_wind_step_during_the_loss_is_not_worse_than_dead_reckoning(w_n_after: float) -> None:
    """Rule 2: 5 s into the loss of n the wind's n component steps from 2 to 3 (or 2.3)
    m/s: nothing measured shows it, the pseudo-measurement of n moves by 1 (0.3) m/s, the
    IMU does not move at all."""
    model = learnt()
    tt, e_ai, e_dr, sigma, ai = _run_loss(
        model, axis=0, accel_bias_mps2=0.02, wind_step=(5.0, (w_n_after, -1.0))
    )
    assert ai.stopped and "disagree with dead reckoning" in ai.stop_reason, ai.stop_reason
    # back on the dead reckoning from the hand-over (measured: 0.1 s after a 1 m/s step,
    # 1.6 s after 0.3 m/s): equal at +10 s and +60 s
    for t_rel in (10.0, float(tt[-1])):
        k = int(np.searchsorted(tt, t_rel))
        assert e_ai[k] == pytest.approx(e_dr[k], abs=1e-9)
    # before the stop the filter followed the stale pseudo-measurements by Δ ≤ 0.12 m/s
    # (measured) for ≤ 2 s of the 60: e_ai² − e_dr² ≤ 2 e_dr Δ + Δ² ≈ 0.05 m²/s² over
    # 1/30 of the loss moves the RMS (0.69 m/s) by ≤ 0.0012 m/s; the benchmark's 0.02
    # tolerance is 15× that
    assert np.sqrt(np.mean(e_ai**2)) <= np.sqrt(np.mean(e_dr**2)) + 0.02
    assert np.mean(e_ai <= 2.0 * sigma) >= 0.95


def test_a_model_contradicted_while_learning_refuses_itself() -> None:
    """The model's own rule: 5σ outliers to a model that passed its tests mean it is
    changing (a wind change); more than 5 of them (weighted over 5 s) and it gives no
    pseudo-measurement until they decay, while an isolated glitch of 3 samples does not."""
    model = learnt()
    t = np.arange(120.0, 121.0, 1.0 / RATE_HZ)
    f, E, v, _ = flight(t, seed=5)
    # 3 samples of a 3 m/s glitch in the measured n: residual k · 3 ≈ 1.2 m/s² ≫ 5σ_f
    for i in range(len(t)):
        v_glitch = v[i] + (3.0 if 5 <= i < 8 else 0.0) * np.array([1.0, 0.0, 0.0])
        model.learn(float(t[i]), f[i], E[i], v_glitch)
    assert model.n_outliers == 3
    assert model.trust().ok and model.pseudo_measurement(f[-1], E[-1], v[-1], 0) is not None
    # the wind turns from (2, −1) to (−1, 2) m/s: every sample is an outlier (k·Δu ≈
    # 0.4 · 3 m/s² against 5σ ≈ 0.25): the sixth makes the weighted count exceed 5
    model = learnt()
    t2 = np.arange(120.0, 121.0, 1.0 / RATE_HZ)
    f2, E2, v2, _ = flight(t2, seed=6, wind_ne=(-1.0, 2.0))
    for i in range(5):
        model.learn(float(t2[i]), f2[i], E2[i], v2[i])
    assert model.trust().ok  # 5 outliers, decayed by e^(−0.16/5): 4.9
    model.learn(float(t2[5]), f2[5], E2[5], v2[5])
    tr = model.trust()
    assert not tr.ok and "changing" in tr.reason
    assert model.pseudo_measurement(f2[6], E2[6], v2[6], 0) is None


def _scatter_loss(
    *,
    scale: float,
    model_sigma_mps: float = 0.0,
    seed: int = 0,
    rate_hz: float = 5.0,
) -> tuple[AidedAxis, float, float | None]:
    """Rule 4 alone: n lost at t = 0, the IMU biased by 0.03 m/s² (dead reckoning ramps,
    0.6 σ_b: rule 2 quiet), pseudo-measurements of n at 5 Hz (a GPS's rate) stating σ =
    0.1 m/s (or √(0.1² + σ_m²) with a model part σ_m) whose white part really is
    ``scale`` × 0.1 and whose model part is a Gauss-Markov error of σ_m, τ 10 s (the
    filter's ``model_corr_time_s``). The hand-over's σ is 0.5 m/s so that rule 2
    (level against dead reckoning) stays out of the way. Returns the filter, the
    largest mean scatter and when it stopped (None: never)."""
    rng = np.random.default_rng(seed)
    ax = AidedAxis(0, 0.0, 0.5, 0.0)
    dt = 1.0 / rate_hz
    phi = math.exp(-dt / 10.0)
    m = rng.normal(0.0, model_sigma_mps)
    sigma = math.hypot(0.1, model_sigma_mps)
    largest = 0.0
    t_stop: float | None = None
    for i in range(1, int(60.0 * rate_hz) + 1):
        t = i * dt
        truth = 2.0 * math.sin(0.2 * t)
        ax.propagate(dt, (0.4 * math.cos(0.2 * t) + 0.03, 0.0, 0.0))
        m = phi * m + math.sqrt(1.0 - phi * phi) * model_sigma_mps * rng.normal()
        z = truth + m + rng.normal(0.0, scale * 0.1)
        ax.update(PseudoMeasurement(z, sigma, model_sigma_mps))
        if not math.isnan(ax.scatter_mean_z2):
            largest = max(largest, ax.scatter_mean_z2)
        if ax.stopped and t_stop is None:
            t_stop = t
    return ax, largest, t_stop


def test_pseudo_measurements_as_scattered_as_their_sigma_say_are_kept() -> None:
    """Rule 4 raises no alarm on a model whose σ is right, white or slowly varying."""
    cfg = AidedAxisConfig()
    ax, largest, t_stop = _scatter_loss(scale=1.0)
    # white errors of the stated σ: the mean z² about the trend is ≈ 1 less the trend's
    # share; its 60 s maximum was 1.28-1.48 over 5 seeds (50 samples per 10 s window:
    # σ of the mean ≈ √(2/50) = 0.2, so the threshold 2 is ≥ 2.6σ above it)
    assert t_stop is None and not ax.stopped and ax.state().aided
    assert 1.0 <= largest < cfg.scatter_max
    # a model part of 0.3 m/s (3 × the white part) moving with τ 10 s: it moves with the
    # 10 s trend and is not scatter (measured maximum 0.35-0.63 over 5 seeds)
    ax, largest, t_stop = _scatter_loss(scale=1.0, model_sigma_mps=0.3)
    assert t_stop is None and not ax.stopped
    assert largest < 1.0


def test_pseudo_measurements_scattering_beyond_their_sigma_fall_back() -> None:
    """Rule 4: a model whose pseudo-measurements scatter 3× their σ (the corpus quad's
    out-of-sample errors were 2-4σ) is refused once the window is judged, and the axis
    is the dead reckoning from then on."""
    cfg = AidedAxisConfig()
    ax, largest, t_stop = _scatter_loss(scale=3.0)
    assert ax.stopped and "scatter beyond their σ" in ax.stop_reason
    # judged after the trend's 1 s and a full window's weight (1 − e⁻¹ of 10 s of
    # updates, ≈ 10 s): measured 11.2 s; the mean z² is ≈ 9 (3²) by then (measured 8.1-10.4
    # over 5 seeds), far above the threshold: more than twice it
    assert t_stop is not None
    assert cfg.scatter_trend_min_s + cfg.scatter_window_s * (1.0 - math.exp(-1.0)) <= t_stop
    assert t_stop <= cfg.scatter_trend_min_s + cfg.scatter_window_s + 0.5
    assert largest > 2.0 * cfg.scatter_max
    assert ax.v_mps == ax.v_dr_mps and not ax.state().aided
    assert "scatter" in ax.state().why


def test_a_model_less_certain_than_dead_reckoning_leaves_the_axis_on_it() -> None:
    """Rule 5: the estimate after an update is at least as uncertain as the
    pseudo-measurement's model part σ_m (common to every update); a pseudo-measurement
    whose σ_m exceeds the dead reckoning's σ leaves the axis on the dead reckoning, not
    on a value the filter itself says is worse; aiding goes on from there."""
    ax = AidedAxis(0, 0.0, 0.1, 0.0)
    # 1 s of IMU: dead reckoning's σ² = 0.1² + 0.05² · 1 + 0.05² · 1² = 0.015 (0.122 m/s)
    for _ in range(25):
        ax.propagate(0.04, (0.04, 0.0, 0.0))
    assert ax.P_dr_mps2 == pytest.approx(0.015)
    # σ_m = 0.3 m/s > 0.122: not fused; v and P are the dead reckoning's
    assert not ax.update(PseudoMeasurement(0.5, 0.31, 0.3))
    assert ax.n_dr_better == 1 and ax.n_accepted == 0 and not ax.stopped
    assert ax.v_mps == ax.v_dr_mps == pytest.approx(0.04)
    st = ax.state()
    assert not st.aided and "not below dead reckoning" in st.why
    # a pseudo-measurement whose model part is small is fused as before
    ax.propagate(0.04, (0.0, 0.0, 0.0))
    assert ax.update(PseudoMeasurement(0.1, 0.1, 0.02))
    assert 0.04 < ax.v_mps < 0.1 and ax.state().aided
    # after a good update, a model part above the dead reckoning's σ sets it back on it
    # (the estimate would claim σ ≥ 0.3 > 0.123: worse than the dead reckoning)
    assert not ax.update(PseudoMeasurement(0.5, 0.31, 0.3))
    assert ax.v_mps == ax.v_dr_mps and ax.n_dr_better == 2
