"""ArduPilot SITL's floor model (``glmav_testkit.ardupilot_floor``) and the measurement of the
estimator's input error (``benchmarks.aero_floor``): the drag law read from ArduPilot's
frame model against what the service's own drag model learns on a tuning flight, the
sidecar's wind windows, and the input error's random walk recovered from a synthetic
flight whose random walk is known."""

from __future__ import annotations

import math

import numpy as np
from benchmarks.aero import CORPUS, Flight, flight_from_samples, tlog_samples
from benchmarks.aero_floor import input_error_random_walk

from glmav_observer.estimation.aero import DragModel
from glmav_observer.estimation.aero.floor import sigma_after_loss_mps
from glmav_testkit.ardupilot_floor import (
    ardupilot_floor_model,
    frame_drag,
    mean_wind_ne_mps,
    sidecar,
    turbulence_sigma_h_mps,
    wind_params_at,
)
from glmav_testkit.fault_replay import read_log_bytes


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
