"""Input stream timing: mean intervals and the measurement gone missing."""

from __future__ import annotations

import math

from glmav_observer.estimation.streams import StreamTiming


def test_intervals_are_running_means_seeded_by_the_first_and_capped_at_the_gap() -> None:
    s = StreamTiming(max_gap_s=1.0, missing_timeout_s=0.5)
    assert s.imu_hz == 0.0
    for k in range(200):  # 250 Hz
        s.imu(0.004 * k)
    assert math.isclose(s.imu_interval_s, 0.004, rel_tol=1e-9)
    assert math.isclose(s.imu_hz, 250.0, rel_tol=1e-9)
    s.imu(0.796 + 5.0)  # a 5 s hole counts as max_gap_s: 0.004 + 0.02 (1.0 − 0.004)
    assert math.isclose(s.imu_interval_s, 0.004 + 0.02 * (1.0 - 0.004), rel_tol=1e-9)
    for k in range(1, 31):  # 10 Hz measurement, seeded by its first interval
        s.measurement(0.1 * k)
    assert math.isclose(s.y_interval_s, 0.1, rel_tol=1e-9)


def test_missing_once_after_the_timeout_and_cleared_by_the_next_measurement() -> None:
    s = StreamTiming(max_gap_s=1.0, missing_timeout_s=0.5)
    assert not s.check_missing(100.0)  # no interval known yet: never "missing"
    for k in range(1, 11):  # 5 Hz: timeout max(0.5, 3.5 × 0.2) = 0.7 s
        s.measurement(0.2 * k)
    assert not s.check_missing(2.0 + 0.69)
    assert s.check_missing(2.0 + 0.71)
    assert not s.check_missing(2.0 + 0.8)  # reported once
    assert s.missing
    s.measurement(3.0)
    assert not s.missing
