"""The lost-axis floor (estimation/aero/floor.py): its Riccati recursion pinned to the
closed forms (F5) and the dead reckoning's, its numbers for glmav-sitl's own sensors and
winds against issue 13's bounds, and the oracle filter run on a simulated flight."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from glmav_observer.estimation.aero.floor import (
    FloorFilter,
    FloorModel,
    double_integrator_pvv_m2ps2,
    mean_square_relative_std,
    median_abs_error_mps,
    p_within,
    sigma_after_loss_mps,
    steady_state,
)
from glmav_sitl.dynamics.frames import rotate_body_to_ned
from glmav_sitl.scenario import load_scenario
from glmav_sitl.sensors.models import ImuModel
from glmav_sitl.simulator import Simulator
from glmav_sitl.wind import WindConfig, WindModel
from glmav_testkit.aero_floor import sitl_floor_model

# issue 13's bounds, m/s (as in benchmarks/aero.py)
BOUND_10S_MEDIAN = 0.1
BOUND_10S_WORST = 0.2
BOUND_60S = 0.3
#: lost-axis cases per glmav-sitl flight in `python -m benchmarks.aero` (5 losses × n, e)
CASES_PER_FLIGHT = 10

N_B = 6e-3  # m/s³/√Hz, glmav-sitl's accelerometer bias random walk
R_GUSTS = 2.0 * 0.8**2 * 1.0  # m²/s, 2σ_w²τ_w of `gusts`


def _model(**kw: float) -> FloorModel:
    base: dict[str, float] = {
        "accel_noise_density": 0.0,
        "accel_bias_random_walk": N_B,
        "turbulence_sigma_mps": 0.8,
        "turbulence_time_constant_s": 1.0,
        "velocity_rate_hz": 30.0,
        "velocity_sigma_mps": 0.05,
    }
    return FloorModel(**(base | kw))


def test_white_measurement_noise_gives_the_double_integrators_closed_form() -> None:
    # (F5) exactly in its assumptions: no turbulence state, the drag measurement's own
    # white noise of PSD r (discrete variance r/Δt), q_a = 0. The discrete posterior
    # differs from the continuous filter by O(Δt/T_f): T_f = (r/q_b)^¼ = 13.7 s, Δt 10 ms.
    rate = 100.0
    m = _model(
        turbulence_sigma_mps=0.0, drag_sigma_mps=math.sqrt(R_GUSTS * rate), velocity_rate_hz=rate
    )
    p = steady_state(m)
    qb = N_B**2
    assert p[0, 0] == pytest.approx(double_integrator_pvv_m2ps2(qb, R_GUSTS), rel=2e-3)
    assert p[0, 1] == pytest.approx(-math.sqrt(qb * R_GUSTS), rel=2e-3)  # v̇ = −b + …
    assert p[1, 1] == pytest.approx(math.sqrt(2.0) * qb**0.75 * R_GUSTS**0.25, rel=2e-3)
    # the number quoted in the module's docstring and the docs: σ = 0.363 m/s
    assert math.sqrt(double_integrator_pvv_m2ps2(qb, R_GUSTS)) == pytest.approx(0.3631, abs=1e-4)


def test_gauss_markov_turbulence_tends_to_the_closed_form_as_its_time_constant_shrinks() -> None:
    # Same r = 2σ_w²τ_w, shorter τ_w: the Gauss-Markov spectrum r/(1 + ω²τ_w²) is white
    # up to ever higher frequencies, so P_vv → (F5). Its roll-off removes noise the filter
    # would see, so the floor is below (F5), by a relative amount ∝ τ_w/T_f.
    pvv_cf = double_integrator_pvv_m2ps2(N_B**2, R_GUSTS)
    gaps = []
    for tau in (1.0, 0.25, 0.1):  # 100 Hz: Δt ≤ τ_w/10
        m = _model(
            turbulence_time_constant_s=tau,
            turbulence_sigma_mps=math.sqrt(R_GUSTS / (2.0 * tau)),
            velocity_rate_hz=100.0,
        )
        gaps.append(1.0 - steady_state(m)[0, 0] / pvv_cf)
    assert all(g > 0.0 for g in gaps)
    assert gaps[0] > gaps[1] > gaps[2]
    # ∝ τ_w: 1 s → 0.1 s divides the gap by ~10 (measured: 0.097, 0.025, 0.0096)
    assert gaps[0] / gaps[2] == pytest.approx(10.0, rel=0.1)
    assert gaps[2] < 0.01


def test_dead_reckoning_is_the_closed_form_and_the_aided_floor_never_above_it() -> None:
    m = _model(accel_noise_density=4e-3)
    p0 = np.diag([0.1**2, 0.03**2, 0.8**2])
    t = np.array([0.0, 1.0, 10.0, 30.0, 60.0])
    s_dr = sigma_after_loss_mps(m, t, aided=False, p0=p0)
    # v = v0 − b0 t + ∫n_a + ∫∫n_b from an uncorrelated start
    expected = np.sqrt(0.1**2 + 0.03**2 * t**2 + 4e-3**2 * t + N_B**2 * t**3 / 3.0)
    np.testing.assert_allclose(s_dr, expected, rtol=1e-9)
    s_ai = sigma_after_loss_mps(m, np.linspace(0.0, 60.0, 601), p0=p0)
    s_dr_all = sigma_after_loss_mps(m, np.linspace(0.0, 60.0, 601), aided=False, p0=p0)
    # the optimal filter with one more measurement never has the larger variance
    assert np.all(s_ai <= s_dr_all + 1e-12)
    # and from the hand-over it tends to the steady state
    assert s_ai[-1] == pytest.approx(math.sqrt(steady_state(m)[0, 0]), rel=0.02)


def test_gaussian_helpers() -> None:
    assert p_within(median_abs_error_mps(0.3), 0.3) == pytest.approx(0.5, abs=1e-12)
    assert p_within(2.0, 1.0) == pytest.approx(0.9545, abs=1e-4)
    # one sample of e²: Var = 2σ⁴, relative std √2 (χ² with one degree of freedom)
    assert mean_square_relative_std(_model(), 1) == pytest.approx(math.sqrt(2.0), rel=1e-12)


def test_bad_model_values_are_refused() -> None:
    with pytest.raises(ValueError, match="turbulence_time_constant_s"):
        _model(turbulence_time_constant_s=0.0)
    with pytest.raises(ValueError, match="accel_bias_random_walk"):
        _model(accel_bias_random_walk=-1.0)
    with pytest.raises(ValueError, match=">= 0"):
        sigma_after_loss_mps(_model(), np.array([-1.0]))


def _floor(model: FloorModel) -> tuple[float, float, float]:
    """σ at +10 s and +60 s after a hand-over from the healthy steady state, steady σ."""
    s10, s60 = sigma_after_loss_mps(model, np.array([10.0, 60.0]))
    return float(s10), float(s60), math.sqrt(steady_state(model)[0, 0])


def test_the_issues_bounds_in_glmav_sitls_winds() -> None:
    # glmav-sitl's own numbers (sitl.toml [imu], the scenarios' [wind.turbulence], the
    # LOCAL_POSITION_NED rate and noise), read through its loaders.
    gusts = sitl_floor_model("gusts", 0)
    assert gusts.accel_bias_random_walk == 6e-3 and gusts.turbulence_sigma_mps == 0.8
    g10, g60, g_ss = _floor(gusts)
    # `gusts` (σ_w 0.8 m/s, τ_w 1 s): the floor reaches its steady state within the 60 s
    assert g10 == pytest.approx(0.137, abs=1e-3)
    assert g60 == pytest.approx(0.344, abs=1e-3)
    assert g_ss == pytest.approx(0.345, abs=1e-3)
    # 60 s ≤ 0.3 for every case: each case of even the oracle meets it with probability
    # erf(0.3/(√2·0.344)) = 0.62, so ~4 of the benchmark's 10 cases per flight miss it
    # (the cases overlap in time, so not independent: the per-case number is the claim)
    assert g60 > BOUND_60S
    assert p_within(BOUND_60S, g60) == pytest.approx(0.617, abs=0.005)
    # its median (0.674 σ = 0.23) would hold: only the worst case is out of reach
    assert median_abs_error_mps(g60) < BOUND_60S
    # 10 s: the median holds at the floor (0.674 × 0.137 = 0.092 ≤ 0.1, barely), the worst
    # ≤ 0.2 per case with probability 0.86 only
    assert median_abs_error_mps(g10) == pytest.approx(0.0925, abs=1e-3)
    assert median_abs_error_mps(g10) < BOUND_10S_MEDIAN
    assert p_within(BOUND_10S_WORST, g10) == pytest.approx(0.856, abs=0.005)

    # `gusts` with the `autopilot` profile (10 Hz GPS velocity, σ 0.08: the hand-over knows
    # v and b less well): even the 10 s median is out of reach (0.674 × 0.155 = 0.105)
    g10_ap, g60_ap, _ = _floor(sitl_floor_model("gusts", 0, sensor_profile="autopilot"))
    assert g10_ap == pytest.approx(0.155, abs=1e-3)
    assert median_abs_error_mps(g10_ap) > BOUND_10S_MEDIAN
    assert g60_ap == pytest.approx(0.344, abs=1e-3)

    # `autopilot-cruise` (σ_w 0.5 m/s horizontally, 10 Hz velocity, σ 0.08): 60 s lower,
    # still above the bound in 21 % of the cases; with 10 cases, all ten within 0.3 has a
    # probability below 0.1 (if they were independent)
    cruise = sitl_floor_model("autopilot-cruise", 0)
    assert cruise.turbulence_sigma_mps == 0.5 and cruise.velocity_rate_hz == 10.0
    c10, c60, _ = _floor(cruise)
    assert c10 == pytest.approx(0.146, abs=1e-3)
    assert median_abs_error_mps(c10) == pytest.approx(0.0988, abs=1e-3)  # ≤ 0.1, barely
    assert c60 == pytest.approx(0.239, abs=1e-3)
    assert p_within(BOUND_60S, c60) == pytest.approx(0.790, abs=0.005)
    assert p_within(BOUND_60S, c60) ** CASES_PER_FLIGHT < 0.1

    # A calmer wind: the constant 2 m/s with turbulence 0.2 m/s: the 60 s bound holds for
    # 99 % of the cases; the +10 s worst ≤ 0.2 still for 95 % only (the bias random walk
    # over 10 s before the drag has averaged the turbulence down)
    sc = load_scenario("gusts")
    calm = dataclasses.replace(
        sc, wind=WindConfig(constant_ned_mps=(2.0, 0.0, 0.0), turbulence_sigma_mps=(0.2,) * 3)
    )
    k10, k60, _ = _floor(sitl_floor_model(calm, 0))
    assert k10 == pytest.approx(0.101, abs=1e-3)
    assert k60 == pytest.approx(0.116, abs=1e-3)
    assert p_within(BOUND_60S, k60) > 0.99
    assert median_abs_error_mps(k10) < BOUND_10S_MEDIAN
    assert p_within(BOUND_10S_WORST, k10) == pytest.approx(0.952, abs=0.005)
    # turbulence 0.1 m/s: every bound holds for > 99.7 % of the cases
    calmer = dataclasses.replace(
        calm, wind=dataclasses.replace(calm.wind, turbulence_sigma_mps=(0.1,) * 3)
    )
    m10, m60, _ = _floor(sitl_floor_model(calmer, 0))
    assert p_within(BOUND_10S_WORST, m10) > 0.997
    assert p_within(BOUND_60S, m60) > 0.9999


def test_the_oracle_filter_on_a_simulated_flight_has_the_floors_error() -> None:
    """The oracle (F1)-(F4) on a real glmav-sitl flight (`gusts`, the simulator's own IMU
    error process and turbulence): healthy for 20 s, then n and e lost for 120 s with the
    perfect drag measurement z_u = v − w_turb (airspeed + the mean wind and gusts)."""
    dt_s, every = 4e-3, 8  # the control period as RK4 step (the wind and the controller
    # tick at 250 Hz either way); a velocity sample every 32 ms
    rate_hz = 1.0 / (dt_s * every)
    t_healthy_s, t_lost_s = 20.0, 120.0
    sim = Simulator("gusts", seed=1, dt_s=dt_s)
    assert isinstance(sim.imu, ImuModel)
    # the deterministic wind (mean and gusts) the oracle knows: wind.py without turbulence
    det = WindModel(
        dataclasses.replace(sim.scenario.wind, turbulence_sigma_mps=(0.0, 0.0, 0.0)),
        np.random.default_rng(0),
    )
    axes = (0, 1)
    models = [sitl_floor_model(sim.scenario, ax, velocity_rate_hz=rate_hz) for ax in axes]
    tr = sim.truth()
    filters = [
        FloorFilter(
            m,
            np.array([tr.v_ned_mps[ax], 0.0, 0.0]),
            np.diag([m.velocity_sigma_mps**2, 0.2**2, m.turbulence_sigma_mps**2]),
        )
        for ax, m in zip(axes, models, strict=True)
    ]
    v_prev = np.array(tr.v_ned_mps)
    dv = np.zeros(3)
    err: list[list[float]] = []
    pvv: list[float] = []
    p_handover = None
    n = 0
    while sim.t_s < t_healthy_s + t_lost_s - 1e-9:
        sim.step()
        n += 1
        tr = sim.truth()
        v = np.array(tr.v_ned_mps)
        # the accelerometer reads the step's mean specific force plus the simulator's own
        # error (turn-on bias, bias random walk, white noise at 250 Hz): ImuModel.sample
        # with a zero force returns exactly that error
        _, acc_err_body = sim.imu.sample(sim.t_s, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0 / dt_s)
        dv += (v - v_prev) + np.array(rotate_body_to_ned(tr.q, acc_err_body)) * dt_s
        v_prev = v
        if n % every:
            continue
        w_det = det.update(sim.t_s)
        healthy = sim.t_s <= t_healthy_s + 1e-9
        _, v_meas = sim.position_sensor.sample(sim.t_s, tr.p_ned_m, tr.v_ned_mps)
        for ax, f in zip(axes, filters, strict=True):
            f.predict(float(dv[ax]))
            z_u = float(v[ax] - (tr.wind_ned_mps[ax] - w_det[ax]))
            f.update(z_u, float(v_meas[ax]) if healthy else None)
        dv[:] = 0.0
        if healthy:
            p_handover = filters[0].p.copy()
        else:
            err.append([float(f.x[0] - v[ax]) for ax, f in zip(axes, filters, strict=True)])
            pvv.append(float(filters[0].p[0, 0]))
    assert p_handover is not None
    e = np.asarray(err)
    # 1. the running filter's σ is sigma_after_loss_mps's from its own hand-over
    t_rel = np.arange(1, len(pvv) + 1) / rate_hz
    np.testing.assert_allclose(
        np.sqrt(pvv), sigma_after_loss_mps(models[0], t_rel, p0=p_handover), rtol=1e-9
    )
    # 2. consistency: the mean normalised innovation squared of the lost phase is 1; the
    # innovations of a filter whose model is right are white, so over N of them (two
    # axes) its standard deviation is √(2/N); 3σ. This checks the turbulence (which
    # dominates the innovation: σ_w²(1 − a²) over 32 ms) against wind.py's.
    nis_n = sum(f.nis_n for f in filters)
    nis = sum(f.nis_sum for f in filters) / nis_n
    assert nis == pytest.approx(1.0, abs=3.0 * math.sqrt(2.0 / nis_n))
    # 3. the error itself against the floor, over the last 80 s of the loss (σ within 2 %
    # of its steady state 0.345 m/s there). The error's correlation time is the filter's
    # T_f ≈ 14 s, so 80 s of one axis are only a few independent samples: the relative
    # standard deviation of its mean square is 0.58 (mean_square_relative_std), 0.41 over
    # the two independent axes; 3σ. (A 20 % agreement of the RMS at 3σ would need ~19
    # such axis-flights, ~25 min of simulated flight: `python -m benchmarks.aero` reports
    # the floor beside the benchmark's errors instead.)
    late = int(40.0 * rate_hz)
    p_late = float(np.mean(pvv[late:]))
    assert math.sqrt(p_late) == pytest.approx(math.sqrt(steady_state(models[0])[0, 0]), rel=0.02)
    rel = mean_square_relative_std(models[0], len(e) - late) / math.sqrt(len(axes))
    ms_ratio = float(np.mean(e[late:] ** 2)) / p_late
    assert ms_ratio == pytest.approx(1.0, abs=3.0 * rel)
    # measured (seed 1): RMS 0.386 (n) and 0.300 (e) m/s against σ 0.344, mean-square
    # ratio 1.008 (the seed is fixed: the number is pinned, its spread is the line above)
    assert ms_ratio == pytest.approx(1.008, abs=0.005)
