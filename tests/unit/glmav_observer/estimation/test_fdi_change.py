"""The accelerometer-change classifier on constructed residuals."""

from __future__ import annotations

import math

import numpy as np

from glmav_observer.estimation.fdi_change import MIN_PRE_SAMPLES, classify_change

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
