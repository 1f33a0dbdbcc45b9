"""Sensor models: IMU, attitude, position/velocity, with noise, bias and scheduled faults.

Every random draw comes from a seeded :class:`numpy.random.Generator` handed in by
the caller (one per sensor, spawned from one :class:`numpy.random.SeedSequence`).

- IMU (gyro rad/s, accelerometer m/s^2, FRD): ``y = x + b + n``; ``b`` a turn-on
  bias ``N(0, sigma_b^2)`` plus a random walk of density ``q_b``
  (``b_{k+1} = b_k + q_b sqrt(dt) n``); ``n`` white with per-sample standard
  deviation ``density * sqrt(rate)`` (a band-limited average over one sample
  period). The accelerometer measures the specific force (F - weight)/m.
- ATTITUDE: ZYX angles + white ``N(0, sigma_att^2)``; rates = true rates + white
  noise at the gyro density (an autopilot's bias-corrected rates).
- LOCAL_POSITION_NED: position + white ``N(0, sigma_p^2)``, NED velocity
  ``E v`` + white ``N(0, sigma_v^2)``, then the scheduled faults per axis
  (dropout -> NaN, freeze -> the value at fault start, bias, noise burst).
"""

from __future__ import annotations

import math

import numpy as np

from glmav_sitl.scenario import Fault, SensorConfig

Vec3 = tuple[float, float, float]
_AXIS = {"n": 0, "e": 1, "d": 2}
_BLOCK = 1024  # rows of normals drawn at once by ImuModel.sample_fast


class ImuModel:
    """Gyro and accelerometer with turn-on bias, bias random walk and white noise."""

    def __init__(
        self, cfg: SensorConfig, rng: np.random.Generator, faults: tuple[Fault, ...] = ()
    ) -> None:
        c = cfg.imu
        self._rng = rng
        self._noise = cfg.noise_scale if cfg.noise else 0.0
        bscale = cfg.bias_scale if cfg.bias else 0.0
        self._gd = c.gyro_noise_density * self._noise
        self._ad = c.accel_noise_density * self._noise
        self._grw = c.gyro_bias_random_walk * bscale
        self._arw = c.accel_bias_random_walk * bscale
        turn_on = rng.standard_normal(6)
        self.gyro_bias_radps = [float(v) * c.gyro_bias_sigma * bscale for v in turn_on[:3]]
        self.accel_bias_mps2 = [float(v) * c.accel_bias_sigma * bscale for v in turn_on[3:]]
        self._accel_faults = tuple(f for f in faults if f.sensor == "accel")
        self._t_last_s = 0.0
        self._blk: list[list[float]] = []  # sample_fast's pre-drawn normals
        self._blk_i = 0

    def accel_fault_bias(self, t_s: float) -> Vec3:
        bx = by = bz = 0.0
        for f in self._accel_faults:
            if f.t_start_s <= t_s < f.t_end_s:
                bx += f.vector[0]
                by += f.vector[1]
                bz += f.vector[2]
        return (bx, by, bz)

    def sample(
        self, t_s: float, omega_body_radps: Vec3, f_body_mps2: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]:
        """(gyro rad/s, accel m/s^2) in FRD at ``t_s`` for a stream sampled at ``rate_hz``."""
        dt = t_s - self._t_last_s
        if dt > 0.0 and (self._grw > 0.0 or self._arw > 0.0):
            n = self._rng.standard_normal(6)
            s = math.sqrt(dt)
            for i in range(3):
                self.gyro_bias_radps[i] += self._grw * s * float(n[i])
                self.accel_bias_mps2[i] += self._arw * s * float(n[3 + i])
        self._t_last_s = max(self._t_last_s, t_s)
        sr = math.sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        sg = self._gd * sr
        sa = self._ad * sr
        if sg > 0.0 or sa > 0.0:
            w = self._rng.standard_normal(6)
            ng = (sg * float(w[0]), sg * float(w[1]), sg * float(w[2]))
            na = (sa * float(w[3]), sa * float(w[4]), sa * float(w[5]))
        else:
            ng = na = (0.0, 0.0, 0.0)
        fb = self.accel_fault_bias(t_s) if self._accel_faults else (0.0, 0.0, 0.0)
        gb = self.gyro_bias_radps
        ab = self.accel_bias_mps2
        gyro = (
            omega_body_radps[0] + gb[0] + ng[0],
            omega_body_radps[1] + gb[1] + ng[1],
            omega_body_radps[2] + gb[2] + ng[2],
        )
        accel = (
            f_body_mps2[0] + ab[0] + na[0] + fb[0],
            f_body_mps2[1] + ab[1] + na[1] + fb[1],
            f_body_mps2[2] + ab[2] + na[2] + fb[2],
        )
        return gyro, accel

    def sample_fast(
        self, t_s: float, omega_body_radps: Vec3, f_body_mps2: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]:
        """:meth:`sample` for callers at kHz rates (the autopilot profile's fast IMU): the
        same model and statistics, the normal draws taken from blocks of
        ``_BLOCK`` x 12 (one numpy call per block instead of two per sample), so the
        draw order, and the numbers, differ from :meth:`sample`'s."""
        i = self._blk_i
        if i >= len(self._blk):
            self._blk = self._rng.standard_normal((_BLOCK, 12)).tolist()
            i = 0
        self._blk_i = i + 1
        n = self._blk[i]
        dt = t_s - self._t_last_s
        gb = self.gyro_bias_radps
        ab = self.accel_bias_mps2
        if dt > 0.0 and (self._grw > 0.0 or self._arw > 0.0):
            s = math.sqrt(dt)
            g, a = self._grw * s, self._arw * s
            gb[0] += g * n[6]
            gb[1] += g * n[7]
            gb[2] += g * n[8]
            ab[0] += a * n[9]
            ab[1] += a * n[10]
            ab[2] += a * n[11]
        self._t_last_s = max(self._t_last_s, t_s)
        sr = math.sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        sg = self._gd * sr
        sa = self._ad * sr
        fb = self.accel_fault_bias(t_s) if self._accel_faults else (0.0, 0.0, 0.0)
        gyro = (
            omega_body_radps[0] + gb[0] + sg * n[0],
            omega_body_radps[1] + gb[1] + sg * n[1],
            omega_body_radps[2] + gb[2] + sg * n[2],
        )
        accel = (
            f_body_mps2[0] + ab[0] + sa * n[3] + fb[0],
            f_body_mps2[1] + ab[1] + sa * n[4] + fb[1],
            f_body_mps2[2] + ab[2] + sa * n[5] + fb[2],
        )
        return gyro, accel


class AttitudeSensor:
    """ATTITUDE: Euler angles (rad) and body rates (rad/s) with white noise."""

    def __init__(self, cfg: SensorConfig, rng: np.random.Generator) -> None:
        k = cfg.noise_scale if cfg.noise else 0.0
        self._sa = cfg.attitude_sigma_rad * k
        self._gd = cfg.imu.gyro_noise_density * k
        self._rng = rng

    def sample(self, euler_rad: Vec3, omega_body_radps: Vec3, rate_hz: float) -> tuple[Vec3, Vec3]:
        if self._sa <= 0.0 and self._gd <= 0.0:
            return euler_rad, omega_body_radps
        n = self._rng.standard_normal(6)
        sa = self._sa
        sg = self._gd * math.sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        phi = euler_rad[0] + sa * float(n[0])
        theta = euler_rad[1] + sa * float(n[1])
        psi = euler_rad[2] + sa * float(n[2])
        psi = math.atan2(math.sin(psi), math.cos(psi))  # keep (-pi, pi]
        return (phi, theta, psi), (
            omega_body_radps[0] + sg * float(n[3]),
            omega_body_radps[1] + sg * float(n[4]),
            omega_body_radps[2] + sg * float(n[5]),
        )


class PositionVelocitySensor:
    """LOCAL_POSITION_NED with GNSS-like white noise and per-axis velocity faults."""

    def __init__(
        self,
        cfg: SensorConfig,
        rng: np.random.Generator,
        fault_rng: np.random.Generator,
        faults: tuple[Fault, ...] = (),
    ) -> None:
        k = cfg.noise_scale if cfg.noise else 0.0
        self._sp = cfg.position_sigma_m * k
        self._sv = cfg.velocity_sigma_mps * k
        self._rng = rng
        self._frng = fault_rng
        self._faults = tuple(f for f in faults if f.sensor == "velocity")
        self._frozen: dict[int, float] = {}
        self._last_v: list[float] = [0.0, 0.0, 0.0]

    @property
    def velocity_sigma_mps(self) -> float:
        return self._sv

    def set_velocity_sigma_mps(self, sigma_mps: float) -> None:
        """Change the velocity noise at run time (a ground station's parameter)."""
        self._sv = sigma_mps

    def set_faults(self, faults: tuple[Fault, ...]) -> None:
        """Replace the velocity faults (a ground station's fault injection)."""
        self._faults = tuple(f for f in faults if f.sensor == "velocity")
        self._frozen.clear()

    def sample(self, t_s: float, p_ned_m: Vec3, v_ned_mps: Vec3) -> tuple[Vec3, Vec3]:
        if self._sp > 0.0 or self._sv > 0.0:
            n = self._rng.standard_normal(6)
            sp, sv = self._sp, self._sv
            pos = (
                p_ned_m[0] + sp * float(n[0]),
                p_ned_m[1] + sp * float(n[1]),
                p_ned_m[2] + sp * float(n[2]),
            )
            vel = [
                v_ned_mps[0] + sv * float(n[3]),
                v_ned_mps[1] + sv * float(n[4]),
                v_ned_mps[2] + sv * float(n[5]),
            ]
        else:
            pos = p_ned_m
            vel = list(v_ned_mps)
        for i, f in enumerate(self._faults):
            ax = _AXIS[f.axis]
            if not f.t_start_s <= t_s < f.t_end_s:
                self._frozen.pop(i, None)
                continue
            if f.kind == "dropout":
                vel[ax] = math.nan
            elif f.kind == "freeze":
                vel[ax] = self._frozen.setdefault(i, self._last_v[ax])
            elif f.kind == "bias":
                vel[ax] += f.magnitude
            elif f.kind == "noise":
                vel[ax] += f.magnitude * float(self._frng.standard_normal())
        self._last_v = list(vel)
        return pos, (vel[0], vel[1], vel[2])
