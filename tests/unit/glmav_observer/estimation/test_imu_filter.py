"""The accelerometer filter's delay: its value, where it comes from, and what the
estimator does with it (estimation/imu_filter.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from glmav_observer.estimation.imu_filter import (
    accel_filter_delay_s,
    firmware_accel_filter_hz,
    lowpass2_group_delay_s,
)
from glmav_observer.estimation.vehicle import EstimatorConfig, VehicleEstimator


def test_group_delay_of_the_two_pole_butterworth_at_dc() -> None:
    # √2/(2π·20 Hz) = 11.254 ms, ArduPilot's default; 0 for no filter
    assert lowpass2_group_delay_s(20.0) == pytest.approx(0.0112540, abs=1e-7)
    assert lowpass2_group_delay_s(0.0) == 0.0
    # against the filter itself: the discrete biquad ArduPilot runs (LowPassFilter2p,
    # bilinear with prewarping) at 1 kHz on a slow ramp lags it by the same delay
    fs, fc = 1000.0, 20.0
    ohm = math.tan(math.pi * fc / fs)
    c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
    b0 = ohm * ohm / c
    b1, b2 = 2.0 * b0, b0
    a1 = 2.0 * (ohm * ohm - 1.0) / c
    a2 = (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c
    x = np.arange(2000) / fs  # a ramp of 1/s: the output settles 1 x delay behind it
    y = np.zeros_like(x)
    for k in range(2, len(x)):
        y[k] = b0 * x[k] + b1 * x[k - 1] + b2 * x[k - 2] - a1 * y[k - 1] - a2 * y[k - 2]
    # the continuous filter's delay, to the discretisation's (fc/fs)² order: 0.1 ms
    assert x[-1] - y[-1] == pytest.approx(lowpass2_group_delay_s(fc), abs=1e-4)


def test_the_firmwares_default_and_the_configured_cutoff() -> None:
    assert firmware_accel_filter_hz(3, 2) == 20.0  # ArduPilot quad
    assert firmware_accel_filter_hz(3, 10) == 10.0  # ArduPilot Rover
    assert firmware_accel_filter_hz(12, 2) == 0.0  # PX4: not assumed
    assert accel_filter_delay_s(0.0, None, None) == 0.0  # no HEARTBEAT yet
    assert accel_filter_delay_s(0.0, 3, 2) == lowpass2_group_delay_s(20.0)
    assert accel_filter_delay_s(40.0, 3, 2) == lowpass2_group_delay_s(40.0)  # configured
    assert accel_filter_delay_s(40.0, None, None) == lowpass2_group_delay_s(40.0)


@pytest.mark.parametrize(
    ("compensate", "hz", "expected_s"),
    [
        (True, 0.0, lowpass2_group_delay_s(20.0)),
        (True, 30.0, lowpass2_group_delay_s(30.0)),
        (False, 30.0, 0.0),
    ],
)
def test_the_estimator_takes_the_delay_from_its_heartbeat(
    compensate: bool, hz: float, expected_s: float
) -> None:
    cfg = dataclasses.replace(EstimatorConfig(), compensate_imu_filter=compensate, imu_filter_hz=hz)
    est = VehicleEstimator(1, cfg)
    # before the HEARTBEAT: only a configured cutoff is known
    before_s = lowpass2_group_delay_s(hz) if compensate else 0.0
    assert est.bank.imu_lead_s == before_s
    assert est.counters["imu_filter_delay_us"] == round(before_s * 1e6)
    est.set_autopilot(3, 2)
    assert est.bank.imu_lead_s == expected_s
    assert est.counters["imu_filter_delay_us"] == round(expected_s * 1e6)
    est.restart("clock_reset")  # a reboot keeps the vehicle's facts
    assert est.bank.imu_lead_s == expected_s
