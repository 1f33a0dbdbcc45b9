"""The redundant-IMU monitor on synthetic streams: which IMU, how much, onset and end."""

from __future__ import annotations

import math

import numpy as np
import pytest

from glmav_observer.estimation.imu_monitor import ImuConsistency, ImuEvent

G = (0.0, 0.0, -9.80665)


def _run(
    n_imus: int, faulty: int | None, bias: tuple[float, float, float], *, seed: int = 1
) -> tuple[ImuConsistency, list[ImuEvent], list[tuple[float, tuple[float, float, float] | None]]]:
    """20 s at 50 Hz; the bias on IMU ``faulty`` from 8 s to 14 s; 0.004 m/s² of noise per
    sample (ArduPilot's SITL) and a constant calibration offset of 0.03 m/s² on IMU 2."""
    rng = np.random.default_rng(seed)
    mon = ImuConsistency()
    events: list[ImuEvent] = []
    corrections = []
    for k in range(1000):
        t = k * 0.02
        f_true = (0.3 * math.sin(t), 0.2 * math.cos(0.7 * t), G[2])
        on = faulty is not None and 8.0 <= t < 14.0
        for i in range(2, n_imus + 1):
            f = [f_true[a] + rng.normal(0.0, 0.004) for a in range(3)]
            f[0] += 0.03 if i == 2 else 0.0
            if on and faulty == i:
                f = [f[a] + bias[a] for a in range(3)]
            mon.secondary(i, t, (f[0], f[1], f[2]))
        f1 = [f_true[a] + rng.normal(0.0, 0.004) for a in range(3)]
        if on and faulty == 1:
            f1 = [f1[a] + bias[a] for a in range(3)]
        events += mon.primary(t, (f1[0], f1[1], f1[2]))
        corrections.append((t, mon.correction()))
    return mon, events, corrections


@pytest.mark.parametrize("faulty", [1, 2, 3])
def test_three_imus_name_the_faulty_one_with_its_bias(faulty: int) -> None:
    _, events, corr = _run(3, faulty, (0.0, 0.4, 0.0))
    assert [e.kind for e in events] == ["onset", "end"]
    onset, end = events
    assert onset.instance == faulty == end.instance
    # the window's mean of 25 samples of σ 0.004·√2: the estimate within 5 σ (0.006)
    assert onset.bias_body_mps2 == pytest.approx((0.0, 0.4, 0.0), abs=0.006)
    assert all(s < 0.003 for s in onset.sigma_mps2)
    # onset: within one sample of 8 s; published one window (0.5 s) later; the end one
    # window after the bias goes (14 s), plus the window that still holds it
    assert onset.t_onset_s == pytest.approx(8.0, abs=0.021)
    assert onset.t_detect_s == pytest.approx(8.5, abs=0.021)
    assert 14.0 < end.t_detect_s <= 15.0 + 0.021
    # IMU 1 is corrected by its own bias while it is the faulty one, else never
    during = [c for t, c in corr if 9.0 <= t < 14.0]
    if faulty == 1:
        assert all(c is not None and c[1] == pytest.approx(0.4, abs=0.006) for c in during)
    else:
        assert all(c is None for _, c in corr)
    assert all(c is None for t, c in corr if t > 15.1)


def test_two_imus_wait_for_the_velocity_then_name_none() -> None:
    """Two IMUs cannot say which one is wrong: without a resolution the onset is published
    after resolve_timeout_s (3 s), naming none, with f_2 − f_1."""
    _, events, corr = _run(2, 1, (0.5, 0.0, 0.0))
    assert [e.kind for e in events] == ["onset", "end"]
    assert events[0].instance is None
    assert events[0].bias_body_mps2[0] == pytest.approx(-0.5, abs=0.006)
    assert events[0].t_detect_s == pytest.approx(11.0, abs=0.021)
    assert all(c is None for _, c in corr)


def test_two_imus_resolved_to_imu_1_correct_it() -> None:
    mon = ImuConsistency()
    events: list[ImuEvent] = []
    for k in range(1000):
        t = k * 0.02
        mon.secondary(2, t, G)
        f1 = (0.5, 0.0, G[2]) if 8.0 <= t < 14.0 else G
        events += mon.primary(t, f1)
        pending = mon.unresolved()
        if pending is not None and t >= 9.0:
            assert pending[1][0] == pytest.approx(-0.5, abs=0.002)  # (baseline: 1e-3)
            mon.resolve(1)
    assert [(e.kind, e.instance) for e in events] == [("onset", 1), ("end", 1)]
    assert events[0].bias_body_mps2 == pytest.approx((0.5, 0.0, 0.0), abs=0.002)
    assert events[0].t_detect_s == pytest.approx(9.0, abs=0.021)


def test_no_event_without_a_fault_and_an_absent_imu_is_ignored() -> None:
    mon, events, _ = _run(3, None, (0.0, 0.0, 0.0))
    assert events == []
    mon.secondary(4, 20.0, (0.0, 0.0, 0.0))  # ArduPilot's missing IMU 3: exact zeros
    assert mon.instances == 3
