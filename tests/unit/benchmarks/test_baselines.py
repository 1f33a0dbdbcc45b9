"""The baselines of the accuracy suite (benchmarks/baselines.py) on plain data."""

from __future__ import annotations

import math

import numpy as np
from benchmarks.baselines import (
    DeadReckoning,
    KalmanVelocity,
    RawMeasurement,
    earth_accel_mps2,
)

from glmav_observer.estimation.observer import G_MPS2
from glmav_observer.frames import e_exact


def test_earth_accel_is_e_times_f_plus_gravity() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        eul = rng.uniform(-1.5, 1.5, 3)
        f = rng.normal(0.0, 5.0, 3)
        want = e_exact(eul) @ f + np.array([0.0, 0.0, G_MPS2])
        assert np.allclose(earth_accel_mps2(eul.tolist(), f.tolist()), want, atol=1e-12)
    # at rest and level the accelerometer reads -g on z: no acceleration
    assert np.allclose(earth_accel_mps2((0.0, 0.0, 0.0), (0.0, 0.0, -G_MPS2)), 0.0)


def test_dead_reckoning_integrates_and_ignores_measurements() -> None:
    dr = DeadReckoning((1.0, 2.0, 3.0))
    dr.predict(0.5, np.array([2.0, 0.0, -4.0]))
    dr.update((9.0, 9.0, 9.0), (True, True, True))
    assert np.allclose(dr.v_ned_mps, [2.0, 2.0, 1.0])


def test_raw_measurement_holds_the_last_valid_measured_value() -> None:
    raw = RawMeasurement((0.0, 0.0, 0.0))
    raw.update((1.0, 2.0, 3.0), (True, True, False))
    raw.update((4.0, math.nan, 6.0), (True, True, False))
    raw.predict(1.0, np.array([5.0, 5.0, 5.0]))
    assert np.allclose(raw.v_ned_mps, [4.0, 2.0, 0.0])


def test_kalman_matches_the_scalar_closed_form() -> None:
    # one axis, F = 1: after predict P = p0 + q² Δt; the gain is P/(P + r²)
    kf = KalmanVelocity((0.0, 0.0, 0.0), p0_mps2=0.01, accel_noise_density=0.1, sigma_meas_mps=0.2)
    kf.predict(2.0, np.array([1.0, 0.0, 0.0]))
    p = 0.01 + 0.1**2 * 2.0
    k = p / (p + 0.2**2)
    kf.update((3.0, math.nan, 7.0), (True, True, False))  # e NaN, d not measured
    assert math.isclose(kf.v_ned_mps[0], 2.0 + k * (3.0 - 2.0), rel_tol=1e-12)
    assert kf.v_ned_mps[1] == 0.0 and kf.v_ned_mps[2] == 0.0
    assert math.isclose(kf.kf.P[0, 0], (1 - k) * p, rel_tol=1e-12)
    assert math.isclose(kf.kf.P[2, 2], p, rel_tol=1e-12)


def test_kalman_lost_axis_is_dead_reckoning() -> None:
    # a never-measured axis of the KF moves exactly as dead reckoning does
    kf = KalmanVelocity((1.0, 1.0, 1.0))
    dr = DeadReckoning((1.0, 1.0, 1.0))
    rng = np.random.default_rng(0)
    for _ in range(100):
        a = rng.normal(size=3)
        kf.predict(0.01, a)
        dr.predict(0.01, a)
        kf.update(tuple(rng.normal(size=3)), (True, True, False))
    assert math.isclose(kf.v_ned_mps[2], dr.v_ned_mps[2], rel_tol=1e-12)
