"""The pure functions of ``benchmarks.down_floor``: the earth-frame vertical acceleration,
the frame term of a turning body, the trapezoid, causality by arrival and the least
squares the data floor is learnt with."""

from __future__ import annotations

import math

import numpy as np
from benchmarks.down_floor import (
    G0_MPS2,
    age_bins,
    cumulative_trapezoid,
    fit_ridge,
    frame_term_d_mps2,
    latest_arrived,
    vertical_accel_ned_mps2,
)


def test_vertical_accel_is_zero_in_hover_at_any_attitude() -> None:
    # hover: the specific force is gravity's reaction, Eᵀ (0, 0, −g) in body axes
    rng = np.random.default_rng(1)
    eul = rng.uniform([-0.5, -0.5, -math.pi], [0.5, 0.5, math.pi], size=(50, 3))
    phi, theta = eul[:, 0], eul[:, 1]
    f_body = -G0_MPS2 * np.stack(
        [-np.sin(theta), np.sin(phi) * np.cos(theta), np.cos(phi) * np.cos(theta)], axis=1
    )
    # 1e-12 m/s²: rounding of a handful of products of order g
    assert np.abs(vertical_accel_ned_mps2(eul, f_body)).max() < 1e-12
    # level, 1 m/s² less thrust than weight: 1 m/s² down (positive), exactly
    level = np.zeros((1, 3))
    a = vertical_accel_ned_mps2(level, np.array([[0.0, 0.0, -G0_MPS2 + 1.0]]))
    assert math.isclose(float(a[0]), 1.0, abs_tol=1e-12)


def test_frame_term_is_pitch_rate_times_forward_speed() -> None:
    # level, heading north, pitching at q = 0.5 rad/s while flying north at 6 m/s: the
    # body frame turns about east, so a fixed NED velocity's down component, seen from
    # it, changes at −q·v_n = −3 m/s² (ω_e = (0, q, 0); (ω_e × v)_d = ω_n v_e − ω_e v_n)
    eul = np.zeros((1, 3))
    out = frame_term_d_mps2(eul, np.array([[0.0, 0.5, 0.0]]), np.array([[6.0, 0.0, 0.0]]))
    assert math.isclose(float(out[0]), -3.0, abs_tol=1e-12)  # exact up to rounding
    # heading east (ψ = 90°) the same pitch rate turns about south (ω_n = −q): −q·v_e
    eul_e = np.array([[0.0, 0.0, math.pi / 2]])
    out_e = frame_term_d_mps2(eul_e, np.array([[0.0, 0.5, 0.0]]), np.array([[0.0, 6.0, 0.0]]))
    assert math.isclose(float(out_e[0]), -3.0, abs_tol=1e-12)
    # a yaw rate alone never moves the down component
    yaw = frame_term_d_mps2(eul, np.array([[0.0, 0.0, 1.0]]), np.array([[6.0, 2.0, 1.0]]))
    assert abs(float(yaw[0])) < 1e-15


def test_cumulative_trapezoid_is_exact_for_a_linear_signal() -> None:
    t = np.array([0.0, 0.02, 0.05, 0.07, 0.11])  # uneven steps, as a jittery IMU
    x = 2.0 + 3.0 * t
    exact = 2.0 * t + 1.5 * t**2
    assert np.abs(cumulative_trapezoid(t, x) - exact).max() < 1e-15


def test_latest_arrived_counts_only_what_came_before() -> None:
    # velocity samples arrive at 1.0, 2.0, 3.0 (host time); a record made at 2.0 has
    # seen the sample of 2.0 (side="right"), one at 1.9 only the first, one at 0.5 none
    idx = latest_arrived(np.array([1.0, 2.0, 3.0]), np.array([0.5, 1.9, 2.0, 3.5]))
    assert idx.tolist() == [-1, 0, 1, 2]


def test_fit_ridge_recovers_the_weights_of_a_linear_model() -> None:
    rng = np.random.default_rng(7)
    x = rng.normal(size=(4000, 3))
    w = np.array([0.5, -1.0, 2.0])
    y = x @ w + 0.25 + rng.normal(scale=0.01, size=4000)
    got = fit_ridge(x, y)
    # noise 0.01 over 4000 rows: σ of each weight ≈ 0.01/√4000 = 1.6e-4; the ridge
    # (1e-6 relative) shrinks by ~1e-6; 2e-3 is > 10σ
    assert np.abs(got - np.r_[w, 0.25]).max() < 2e-3


def test_age_bins_group_the_ticks_of_a_50_hz_and_a_25_hz_imu() -> None:
    # ArduPilot's ages: 20.5 and 40.5 ms (ms stamps behind µs ones); 40.0 at 25 Hz
    assert age_bins(np.array([0.0205, 0.0405, 0.040, 0.0199])).tolist() == [2, 4, 4, 2]
