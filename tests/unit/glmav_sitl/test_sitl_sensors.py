"""Sensor models, faults and wind: statistics and fault schedules (plain data, no sockets)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from glmav_sitl.scenario import Fault, SensorConfig
from glmav_sitl.sensors.models import AttitudeSensor, ImuModel, PositionVelocitySensor
from glmav_sitl.wind import Gust, WindConfig, WindModel

G = 9.81
HOVER_F = (0.0, 0.0, -G)
ZERO = (0.0, 0.0, 0.0)


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_accelerometer_at_hover_reads_minus_g_noise_free() -> None:
    imu = ImuModel(SensorConfig(noise=False, bias=False), _rng())
    gyro, acc = imu.sample(0.004, ZERO, HOVER_F, 250.0)
    assert acc == (0.0, 0.0, -G) and gyro == ZERO


def test_white_noise_has_density_times_sqrt_rate() -> None:
    cfg = SensorConfig(bias=False)
    imu = ImuModel(cfg, _rng(1))
    rate = 250.0
    n = 20000
    s = np.array([sum(imu.sample(k / rate, ZERO, HOVER_F, rate), ()) for k in range(n)])
    sg = cfg.imu.gyro_noise_density * math.sqrt(rate)  # 5.4e-3 rad/s
    sa = cfg.imu.accel_noise_density * math.sqrt(rate)  # 6.3e-2 m/s^2
    # sample std of n normal draws: relative standard error 1/sqrt(2n) = 0.5 %; allow 3 %
    assert np.allclose(s[:, :3].std(axis=0), sg, rtol=0.03)
    assert np.allclose(s[:, 3:].std(axis=0), sa, rtol=0.03)
    # the mean is (0, 0, -g) within 4 standard errors
    assert np.allclose(s[:, 3:].mean(axis=0), HOVER_F, atol=4 * sa / math.sqrt(n))


def test_turn_on_bias_and_random_walk_statistics() -> None:
    cfg = SensorConfig(noise=False)
    biases = np.array([ImuModel(cfg, _rng(k)).accel_bias_mps2 for k in range(2000)])
    # turn-on bias sigma 0.2 m/s^2 (design.md): 2000 draws, standard error 1.6 %; allow 6 %
    assert biases.std() == pytest.approx(0.2, rel=0.06)
    # random walk: after T seconds the bias moved by q sqrt(T) (std across instances)
    moves = []
    for k in range(400):
        imu = ImuModel(cfg, _rng(10_000 + k))
        b0 = list(imu.accel_bias_mps2)
        imu.sample(100.0, ZERO, HOVER_F, 250.0)
        moves.append(np.subtract(imu.accel_bias_mps2, b0))
    expected = cfg.imu.accel_bias_random_walk * math.sqrt(100.0)
    assert np.std(moves) == pytest.approx(expected, rel=0.1)  # 1200 draws: 2 % s.e.; allow 10 %


def test_same_seed_same_samples_other_seed_other_samples() -> None:
    def draw(seed: int) -> list[float]:
        imu = ImuModel(SensorConfig(), _rng(seed))
        return [v for k in range(10) for v in sum(imu.sample(k * 0.004, ZERO, HOVER_F, 250.0), ())]

    assert draw(5) == draw(5)
    assert draw(5) != draw(6)


def test_noise_and_bias_switches_and_scales() -> None:
    cfg = SensorConfig(noise_scale=2.0, bias=False)
    imu = ImuModel(cfg, _rng(2))
    s = np.array([imu.sample(k / 250, ZERO, HOVER_F, 250.0)[1] for k in range(5000)])
    assert s.std(axis=0) == pytest.approx([2 * 4e-3 * math.sqrt(250)] * 3, rel=0.05)
    att = AttitudeSensor(SensorConfig(noise=False), _rng())
    assert att.sample((0.1, 0.2, 0.3), (1.0, 2.0, 3.0), 100.0) == ((0.1, 0.2, 0.3), (1.0, 2.0, 3.0))


def test_accel_bias_fault_step() -> None:
    f = Fault("accel", "accel_bias", 1.0, 2.0, vector=(0.3, -0.2, 0.1))
    imu = ImuModel(SensorConfig(noise=False, bias=False), _rng(), (f,))
    assert imu.sample(0.5, ZERO, HOVER_F, 250.0)[1] == HOVER_F
    assert imu.sample(1.5, ZERO, HOVER_F, 250.0)[1] == pytest.approx((0.3, -0.2, -G + 0.1))
    assert imu.sample(2.5, ZERO, HOVER_F, 250.0)[1] == HOVER_F


def test_velocity_faults_per_axis() -> None:
    faults = (
        Fault("velocity", "dropout", 1.0, 2.0, axis="d"),
        Fault("velocity", "freeze", 1.0, 2.0, axis="n"),
        Fault("velocity", "bias", 1.0, 2.0, axis="e", magnitude=1.5),
    )
    s = PositionVelocitySensor(SensorConfig(noise=False), _rng(), _rng(1), faults)
    v = (1.0, 2.0, 3.0)
    assert s.sample(0.9, ZERO, v)[1] == v
    _, v1 = s.sample(1.0, ZERO, (7.0, 2.0, 3.0))
    assert v1[0] == 1.0  # frozen at the last value before the fault
    assert v1[1] == 3.5 and math.isnan(v1[2])
    _, v2 = s.sample(1.5, ZERO, (9.0, 0.0, 0.0))
    assert v2[0] == 1.0 and v2[1] == 1.5 and math.isnan(v2[2])
    assert s.sample(2.0, ZERO, (9.0, 0.0, 0.0))[1] == (9.0, 0.0, 0.0)  # t_end exclusive
    burst = Fault("velocity", "noise", 0.0, 100.0, axis="n", magnitude=2.0)
    s = PositionVelocitySensor(SensorConfig(noise=False), _rng(), _rng(3), (burst,))
    x = np.array([s.sample(k * 0.03, ZERO, ZERO)[1] for k in range(3000)])
    assert x[:, 0].std() == pytest.approx(2.0, rel=0.05)  # 3000 draws: 1.3 % s.e.
    assert np.all(x[:, 1:] == 0.0)


def test_position_velocity_noise_sigmas() -> None:
    s = PositionVelocitySensor(SensorConfig(), _rng(4), _rng(5))
    x = np.array([sum(s.sample(0.0, ZERO, ZERO), ()) for _ in range(5000)])
    assert x[:, :3].std(axis=0) == pytest.approx([0.3] * 3, rel=0.05)
    assert x[:, 3:].std(axis=0) == pytest.approx([0.05] * 3, rel=0.05)


def test_one_minus_cosine_gust_and_turbulence() -> None:
    g = Gust(10.0, 2.0, (0.0, 4.0, 0.0))
    w = WindModel(WindConfig(constant_ned_mps=(1.0, 0.0, 0.0), gusts=(g,)), _rng())
    assert w.update(9.0) == (1.0, 0.0, 0.0)
    assert w.update(11.0) == pytest.approx((1.0, 4.0, 0.0))  # peak at mid-gust
    assert w.update(10.5) == pytest.approx((1.0, 2.0, 0.0))  # half-way up: A/2
    assert w.update(12.5) == (1.0, 0.0, 0.0)
    turb = WindModel(
        WindConfig(turbulence_sigma_mps=(0.8, 0.8, 0.4), turbulence_time_constant_s=1.0), _rng(7)
    )
    xs = np.array(
        [turb.update(k * 0.004) for k in range(250_000)]
    )  # 1000 s, ~500 correlation times
    # a Gauss-Markov series of N/tau ~ 1000 independent pieces: std within ~5 %
    assert xs.std(axis=0) == pytest.approx([0.8, 0.8, 0.4], rel=0.1)
    # correlation time: lag-1 s autocorrelation exp(-1) = 0.37
    a = xs[:, 0] - xs[:, 0].mean()
    r = float(np.dot(a[:-250], a[250:]) / np.dot(a, a))
    assert r == pytest.approx(math.exp(-1.0), abs=0.08)


def test_sensor_config_replace_keeps_defaults() -> None:
    c = replace(SensorConfig(), noise=False)
    assert c.velocity_sigma_mps == 0.05 and c.imu.accel_bias_sigma == 0.2
