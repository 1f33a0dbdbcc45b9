"""ArduPilot SITL's floor model (``glmav_testkit.ardupilot_floor``) and the measurement of the
estimator's input error (``benchmarks.aero_floor``): the drag law read from ArduPilot's
frame model against what the service's own drag model learns on a tuning flight, the
sidecar's wind windows, and the input error's random walk recovered from a synthetic
flight whose random walk is known."""

from __future__ import annotations

import math

import numpy as np
from benchmarks.aero import CORPUS, Flight, flight_from_samples, tlog_samples
from benchmarks.aero_floor import floor_of_case, input_error_random_walk
from numpy.typing import NDArray

from glmav_observer.estimation.aero import DragModel
from glmav_observer.estimation.aero.floor import (
    MEDIAN_ABS_PER_SIGMA,
    FloorModel,
    double_integrator_pvv_m2ps2,
    sigma_after_loss_mps,
    steady_state,
)
from glmav_sitl.wind import WindConfig, WindModel
from glmav_testkit.ardupilot_floor import (
    MISFIT_MAX_TAU_S,
    ardupilot_floor_model,
    causal_hand_over,
    frame_drag,
    law_misfit_ne_mps,
    mean_wind_ne_mps,
    misfit_statistics,
    sidecar,
    turbulence_sigma_h_mps,
    wind_params_at,
)
from glmav_testkit.fault_replay import read_log_bytes

FloatArray = NDArray[np.float64]


def test_the_frame_models_drag_is_what_the_service_learns_on_a_calm_flight() -> None:
    # SIM_Frame.cpp's default model in hover at 498 m: momentum drag 0.2·√(ρ A m g)/m and
    # ½ρ·areaCd/m (the docstring's derivation)
    quad = frame_drag("quad")
    assert quad.k_x_per_s == quad.k_y_per_s
    assert math.isclose(quad.k_x_per_s, 0.2423, rel_tol=1e-3)
    assert math.isclose(quad.q_per_m, 0.0339, rel_tol=1e-2)
    # the motor count cancels (each motor's √(T/N) · √(A/N) summed over N)
    for frame in ("hexa", "octa"):
        other = frame_drag(frame)
        assert (other.k_x_per_s, other.q_per_m) == (quad.k_x_per_s, quad.q_per_m)
    coax = frame_drag("coaxcopter")
    assert math.isclose(coax.k_x_per_s, 9.80665 / 40.0 / math.sqrt(1.225 / 1.1672), rel_tol=2e-3)
    # the service's drag model on the tuning set's GPS-glitch quad, learnt over the whole
    # flight (before the glitch's window it is the calm quad): k_x within 5 % of the frame
    # model's (measured 0.243 vs 0.242)
    fl = flight_from_samples(
        "h_quad_gps_glitch",
        "ardupilot",
        tlog_samples(read_log_bytes(CORPUS / "h_quad_gps_glitch.tlog.xz")),
    )
    model = DragModel()
    for k in range(len(fl.t_vel_s)):
        model.learn(float(fl.t_vel_s[k]), fl.f_mean_body_mps2[k], fl.E_vel[k], fl.v_meas_ned_mps[k])
    assert abs(model.k_per_s[0] - quad.k_x_per_s) <= 0.05 * quad.k_x_per_s, model.k_per_s
    # and both rows' q (the body's ½ρ·areaCd u|u|) within 10 % (measured 0.0351, 0.0353)
    assert np.all(np.abs(model.q_per_m - quad.q_per_m) <= 0.1 * quad.q_per_m), model.q_per_m


def test_the_wind_in_force_follows_the_sidecars_windows() -> None:
    meta = sidecar(CORPUS / "a_quad_wind.json")
    before = wind_params_at(meta, 60.0)
    during = wind_params_at(meta, 70.0)
    assert before["SIM_WIND_SPD"] == 0.0 and before["SIM_WIND_TURB"] == 0.0
    assert during["SIM_WIND_SPD"] == 4.0 and during["SIM_WIND_TURB"] == 1.0
    # from 180° (south), the wind blows north; √(15/60) of it at 15 m
    w_n, w_e = mean_wind_ne_mps(during, 15.0)
    assert math.isclose(w_n, 2.0, rel_tol=1e-6) and abs(w_e) < 1e-9
    # SIM_Aircraft.cpp's IIR: 10·TURB·0.02/√(1 − 0.98²)
    assert math.isclose(turbulence_sigma_h_mps(1.0), 1.005, rel_tol=1e-3)
    # a loss whose window covers the wind: the turbulence in the floor; before it, none
    m_wind = ardupilot_floor_model(
        meta, 62.0, 60.0, velocity_rate_hz=25.0, imu_rate_hz=50.0, velocity_sigma_mps=0.05
    )
    m_calm = ardupilot_floor_model(
        meta, 0.0, 60.0, velocity_rate_hz=25.0, imu_rate_hz=50.0, velocity_sigma_mps=0.05
    )
    assert m_wind.drag_sigma_mps > 10.0 * m_calm.drag_sigma_mps
    # the oracle with SITL's exact accelerometer and attitude: millimetres per second
    s60 = float(sigma_after_loss_mps(m_wind, np.array([60.0]))[0])
    assert s60 < 0.01


def test_the_input_errors_random_walk_is_recovered() -> None:
    # 3000 s at 50 Hz: truth at rest, the earth acceleration the estimator integrates off
    # by a random walk of N_b = 0.005 m/s³/√Hz plus white noise of 0.05 m/s² per sample
    rng = np.random.default_rng(7)
    rate, n_b = 50.0, 0.005
    t = np.arange(0.0, 3000.0, 1.0 / rate)
    walk = np.cumsum(rng.normal(0.0, n_b / math.sqrt(rate), (t.size, 3)), axis=0)
    a = walk + rng.normal(0.0, 0.05, (t.size, 3))
    zeros = np.zeros((t.size, 3))
    fl = Flight(
        name="synthetic",
        source="test",
        t_imu_s=t,
        a_ned_imu_mps2=a,
        E_imu=np.broadcast_to(np.eye(3), (t.size, 3, 3)),
        t_vel_s=t,
        v_meas_ned_mps=zeros,
        f_mean_body_mps2=zeros,
        E_vel=np.broadcast_to(np.eye(3), (t.size, 3, 3)),
        t_truth_s=t,
        v_truth_ned_mps=zeros,
    )
    got = input_error_random_walk(fl)
    # each axis's estimate is a difference of two variances over ~3000 one-second means:
    # relative spread ~√(2/(3000/30)) ≈ 14 % at lag 30; 3σ ≈ 40 %
    assert np.all(np.abs(got - n_b) <= 0.4 * n_b), got


def _gauss_markov(
    rng: np.random.Generator, n: int, dt_s: float, sigma: float, tau_s: float
) -> FloatArray:
    """(n, 3) stationary first-order Gauss-Markov series, independent per column: glmav-sitl's
    own turbulence process (exact discretisation) sampled every ``dt_s``."""
    wind = WindModel(
        WindConfig(turbulence_sigma_mps=(sigma, sigma, sigma), turbulence_time_constant_s=tau_s),
        rng,
    )
    out: FloatArray = np.array([wind.update(i * dt_s) for i in range(n)])
    return out


def _turning_flight(
    rng: np.random.Generator, n: int, dt_s: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(t, E, v_ned) of a level flight whose heading turns once every 10 min through every
    azimuth, its horizontal velocity a Gauss-Markov process (σ 3 m/s, τ 8 s): a law's
    constants separate from its airspeed terms."""
    t = np.arange(n, dtype=np.float64) * dt_s
    yaw = 2.0 * math.pi * t / 600.0
    c, s = np.cos(yaw), np.sin(yaw)
    e = np.zeros((n, 3, 3))
    e[:, 0, 0], e[:, 0, 1], e[:, 1, 0], e[:, 1, 1], e[:, 2, 2] = c, -s, s, c, 1.0
    v = _gauss_markov(rng, n, dt_s, 3.0, 8.0) * np.array([1.0, 1.0, 0.0])
    return t, e, v


def test_the_misfits_white_and_slow_parts_are_recovered() -> None:
    # one hour at 25 Hz of white noise (σ 0.1 m/s) plus a Gauss-Markov process (σ 0.05,
    # τ 2 s), the shape of the calm flights' misfit with the wind flights' white part
    rng = np.random.default_rng(11)
    dt, n = 0.04, 90_000
    r = rng.normal(0.0, 0.1, n) + _gauss_markov(rng, n, dt, 0.05, 2.0)[:, 0] + 0.3  # + a mean
    got = misfit_statistics(r, dt)
    # the variance of a Gauss-Markov series averaged over T has a relative spread of
    # ~√(2τ/T) = 2.4 %, so its σ ~1.2 %; the autocovariance's other lags alike: 10 % is
    # > 5σ for σ_m and σ_e, and τ (read where C falls to C(1)/e, a ratio of two such
    # estimates, ~4 %) within 20 %
    assert abs(got.slow_sigma_mps - 0.05) <= 0.1 * 0.05, got
    assert abs(got.white_sigma_mps - 0.1) <= 0.1 * 0.1, got
    assert abs(got.slow_tau_s - 2.0) <= 0.2 * 2.0, got
    # white noise alone: its C(1) is ~N(0, σ⁴/n), σ_m ≈ σ·n^(-1/4) = 0.006 σ at most a few
    # times over: below a tenth of the white part
    white = misfit_statistics(rng.normal(0.0, 0.1, n), dt)
    assert white.slow_sigma_mps < 0.01 and abs(white.white_sigma_mps - 0.1) <= 0.01, white


def test_the_law_misfit_is_read_through_the_fit_and_the_rotation() -> None:
    # 40 min at 25 Hz of a quad-like law (k 0.24 1/s, q 0.034 1/m, body biases) whose
    # airspeed reading is off by a Gauss-Markov error (σ 0.04 m/s, τ 2 s) per body axis,
    # flown with the heading turning through every azimuth: the fit must absorb the law's
    # constants and leave that error, rotated to n and e
    rng = np.random.default_rng(5)
    dt, n = 0.04, 60_000
    t, e, v = _turning_flight(rng, n, dt)
    u = np.einsum("kji,kj->ki", e, v)  # body airspeed (no wind)
    du = _gauss_markov(rng, n, dt, 0.04, 2.0)[:, :2]
    k, q, bias = 0.24, 0.034, np.array([0.05, -0.03])
    us = u[:, :2] + du  # what the law reads
    f = np.column_stack([-k * us - q * us * np.abs(us) + bias, np.full(n, -9.8)])
    meta = {"name": "synthetic", "baseline_params": {"SIM_WIND_SPD": 0.0}}
    ok, err = law_misfit_ne_mps(
        meta,
        t,
        v_truth_ned_mps=v,
        height_m=np.full(n, 10.0),
        e_body_to_ned=e,
        f_mean_body_mps2=f,
    )
    assert ok.all()
    # the error read back is −(the body error rotated): its σ and τ those injected (the
    # linearised slope k + 2q|u| differs from the secant by ~q·du: < 1 %), same spread
    # analysis as above over 40 min (~1.5 % on σ): 10 % on σ, 25 % on τ
    for axis in range(2):
        got = misfit_statistics(err[:, axis], dt)
        assert abs(got.slow_sigma_mps - 0.04) <= 0.1 * 0.04, (axis, got)
        assert abs(got.slow_tau_s - 2.0) <= 0.25 * 2.0, (axis, got)
        assert got.white_sigma_mps < 0.2 * 0.04, (axis, got)


def test_a_kept_mean_is_read_as_slow_misfit() -> None:
    # the causal floor keeps the misfit's mean (a law fitted before the loss is off by a
    # constant after it): the series of the test above, mean 0.3 m/s kept. C(L) = m² +
    # σ_m² e^(−L dt/τ) (+ σ_e² at lag 0); m² = 0.09 > C(1)/e ≈ 0.034, so C never falls to
    # C(1)/e: τ is the cap and the slow σ² ≈ C(1) ≈ m² + σ_m² (0.304 m/s)
    rng = np.random.default_rng(11)
    dt, n = 0.04, 90_000
    r = rng.normal(0.0, 0.1, n) + _gauss_markov(rng, n, dt, 0.05, 2.0)[:, 0] + 0.3
    got = misfit_statistics(r, dt, keep_mean=True)
    assert got.slow_tau_s == MISFIT_MAX_TAU_S, got
    # C(1)'s Gauss-Markov share (0.0025 of 0.0925) has the ~1.2 % spread above; the mean
    # is exact: 2 % on the slow σ, 10 % on the white (as above)
    assert abs(got.slow_sigma_mps - math.hypot(0.3, 0.05)) <= 0.02 * 0.304, got
    assert abs(got.white_sigma_mps - 0.1) <= 0.1 * 0.1, got


def test_a_law_fitted_before_the_loss_is_judged_after_it() -> None:
    # a quad-like law read with a Gauss-Markov airspeed error (σ 0.04 m/s, τ 2 s), 40 min
    # at 25 Hz: 10 min of hover (< 0.5 m/s) then flight at up to ~10 m/s in every
    # direction. Fitted on all of it, the misfit over the flight is the injected error;
    # fitted on the hover alone (fit_mask), the law extrapolates: its misfit over the
    # flight, mean kept, is far larger (k, q and the bias are not separable at hover
    # speeds)
    rng = np.random.default_rng(7)
    dt, n, n_hover = 0.04, 60_000, 15_000
    t, e, v = _turning_flight(rng, n, dt)
    v[:n_hover] *= 0.05  # the hover: ≤ ~0.5 m/s
    u = np.einsum("kji,kj->ki", e, v)
    us = u[:, :2] + _gauss_markov(rng, n, dt, 0.04, 2.0)[:, :2]
    f = np.column_stack([-0.24 * us - 0.034 * us * np.abs(us) + 0.05, np.full(n, -9.8)])
    meta = {"name": "synthetic", "baseline_params": {"SIM_WIND_SPD": 0.0}}
    kw = {"v_truth_ned_mps": v, "height_m": np.full(n, 10.0), "e_body_to_ned": e}
    flight = np.arange(n) >= n_hover
    _, err_all = law_misfit_ne_mps(meta, t, f_mean_body_mps2=f, **kw)
    _, err_hover = law_misfit_ne_mps(meta, t, f_mean_body_mps2=f, fit_mask=~flight, **kw)
    for axis in range(2):
        whole = misfit_statistics(err_all[flight, axis], dt, keep_mean=True)
        causal = misfit_statistics(err_hover[flight, axis], dt, keep_mean=True)
        # the whole-flight law leaves the injected error (its mean over 30 min is ~σ√(2τ/T)
        # = 0.002 m/s): 10 % as in the test above
        assert abs(whole.slow_sigma_mps - 0.04) <= 0.1 * 0.04, (axis, whole)
        # the hover's law is off by more than ten times that in flight (measured: ×100s)
        assert causal.slow_sigma_mps > 10.0 * whole.slow_sigma_mps, (axis, causal)


def test_the_causal_hand_over_knows_only_the_known_part() -> None:
    m = FloorModel(
        accel_noise_density=1e-3,
        accel_bias_random_walk=5e-3,
        turbulence_sigma_mps=0.2,
        turbulence_time_constant_s=3.0,
        velocity_rate_hz=10.0,
        velocity_sigma_mps=0.05,
        drag_sigma_mps=0.01,
    )
    healthy = steady_state(m, healthy=True)
    p = causal_hand_over(m, 0.05)
    # the healthy filter's covariance, w's variance grown by the unknown part (0.2² − 0.05²)
    grown = healthy.copy()
    grown[2, 2] += 0.2**2 - 0.05**2
    assert np.allclose(p, grown, rtol=1e-12, atol=0.0)
    # the hand-over knowing less, the aided σ is no smaller at any time after the loss
    # (the Riccati recursion is monotone in P₀; rounding: 1e-12). It is barely larger
    # (measured < 0.1 %): with a slow w the filter cannot tell w from the drift of v
    # whatever it knew at the hand-over, so the misfit's statistics set the floor
    tt = np.array([1.0, 10.0, 60.0])
    known = sigma_after_loss_mps(m, tt)
    unknown = sigma_after_loss_mps(m, tt, p0=p)
    assert np.all(unknown >= known * (1.0 - 1e-12)), (known, unknown)
    # a misfit known in full adds nothing (never a negative variance)
    assert np.allclose(causal_hand_over(m, 0.3), healthy, rtol=0.0, atol=0.0)


def test_the_as_flown_floor_on_the_calm_coax() -> None:
    fl = flight_from_samples(
        "f_coax_clean", "ardupilot", tlog_samples(read_log_bytes(CORPUS / "f_coax_clean.tlog.xz"))
    )
    for axis in range(2):
        case = {"axis": "ne"[axis], "t_loss_s": 65.0}
        got = floor_of_case(fl, case, 60.0, CORPUS)
        slow, white, tau = (
            got["misfit_slow_sigma_mps"],
            got["misfit_white_sigma_mps"],
            got["misfit_slow_tau_s"],
        )
        # calm: the law's misfit is slow, not white (measured slow 0.034/0.043 m/s over
        # τ 2.5/1.2 s, white 0.006/0)
        assert slow > 3.0 * white and tau > 0.5, got
        # a slow misfit is not averaged away: the as-flown floor is far above the oracle's
        # (measured 12×), which averages its white noise down to mm/s
        assert got["asflown_median60_mps"] > 5.0 * got["floor_median60_mps"], got
        # and below the double-integrator limit (F5) with the misfit's low-frequency PSD
        # r = 2σ_m²τ + σ_e²Δt: a Gauss-Markov misfit has at most r at every frequency, so
        # the optimal filter's error is at most that of white noise of PSD r; the IMU's
        # white noise (q_a, neglected in (F5)) adds < 5 % at these levels
        dt = 1.0 / ((len(fl.t_vel_s) - 1) / float(fl.t_vel_s[-1] - fl.t_vel_s[0]))
        r = 2.0 * slow**2 * tau + white**2 * dt
        q_b = got["floor_input_random_walk"] ** 2
        bound = MEDIAN_ABS_PER_SIGMA * math.sqrt(double_integrator_pvv_m2ps2(q_b, r))
        assert got["asflown_median60_mps"] <= 1.05 * bound, (got, bound)
