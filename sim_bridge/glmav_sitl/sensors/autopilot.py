"""The ``autopilot`` sensor profile: what a real autopilot sends, not truth plus white noise.

Everything runs inside the simulator's step (:meth:`AutopilotSensors.update`), on its
own schedules in integer microseconds; the MAVLink side reads the latest outputs
through the same ``sample`` calls as the ``ideal`` profile (:mod:`.models`).

- **Fast IMU** at ``imu_rate_hz`` (default 1 kHz): the accelerometer is the mean specific
  force over the IMU period, ``R^T ((v_k - v_{k-1}) / T - g e_d)`` (a delta-velocity IMU),
  the gyro the true rate at the sample. Both go through :class:`.models.ImuModel`
  (turn-on bias, bias random walk, white noise at the fast rate, scheduled accelerometer
  faults), then **vibration** is added: for each rotor and each harmonic ``h`` of its
  speed, a sinusoid ``A_axis w_h (Omega/Omega_trim)^2 sin(h phi + psi_axis)`` (``phi``
  the rotor angle, ``psi`` a seeded phase per axis), plus broadband white noise.
  RAW_IMU / SCALED_IMU are point samples of this stream at their (slow) rate, so the
  rotor lines alias like a real autopilot's RAW_IMU.
- **Attitude estimator** at ``ahrs_rate_hz`` on the mean of the fast samples since its
  last update: a Mahony complementary filter, ``q <- q exp((w - b + kp e + ky e_psi d) T/2)``,
  ``e = f_m x f_pred / |f_pred|^2`` ( ``f_pred = R^T (a_gps - g e_d)``, ``a_gps`` the
  low-passed derivative of the GPS velocity), ``b <- b - ki e T``; yaw from a compass
  with a constant bias and white noise. The gyro and accelerometer offsets it removes
  are its "boot calibration": the true turn-on biases plus a residual
  (``gyro_cal_sigma_radps``, ``accel_cal_sigma_mps2``). So its errors are correlated,
  biased by the uncalibrated accelerometer residual and by the lag of ``a_gps`` in
  accelerations and turns. ATTITUDE rates: gyro minus the bias estimate, low-passed at
  ``ahrs_rate_filter_hz``.
- **GPS** at ``gps_rate_hz``: truth delayed by ``velocity_lag_s`` minus the filter's own
  delay, plus white noise; then a first-order filter (``velocity_filter_tau_s``) like an
  EKF output. LOCAL_POSITION_NED is the filter's latest output (then the scheduled
  velocity faults, as in ``ideal``), so it lags truth by ``velocity_lag_s`` overall.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from glmav_sitl.dynamics.frames import euler_from_quat, rotate_body_to_ned, rotate_ned_to_body
from glmav_sitl.scenario import AutopilotProfileConfig, Fault, SensorConfig, filter_delay_s
from glmav_sitl.sensors.models import FastImu, ImuModel, PositionVelocitySensor

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


class AutopilotSensors:
    """The fast IMU, the attitude estimator and the filtered GPS of one simulated vehicle.

    ``rngs``: five independent generators (IMU, vibration, calibration and compass, GPS,
    faults). ``rotor_trim_radps`` scales the vibration amplitudes.
    """

    def __init__(
        self,
        cfg: AutopilotProfileConfig,
        sensors: SensorConfig,
        rngs: tuple[
            np.random.Generator,
            np.random.Generator,
            np.random.Generator,
            np.random.Generator,
            np.random.Generator,
        ],
        faults: tuple[Fault, ...],
        *,
        g_mps2: float,
        dt_us: int,
        q0: Quat,
        p0_ned_m: Vec3,
        v0_ned_mps: Vec3,
        rotor_trim_radps: tuple[float, float],
    ) -> None:
        r_imu, r_vib, r_cal, r_gps, r_fault = rngs
        self.cfg = cfg
        self.g_mps2 = g_mps2
        noise = sensors.noise_scale if sensors.noise else 0.0
        bias = sensors.bias_scale if sensors.bias else 0.0  # calibration residuals, compass
        # --- fast IMU: the [imu] errors at the fast rate, broadband vibration folded into
        # the white noise (density^2 + broadband^2 / rate, then the noise scale)
        self.imu_interval_us = max(dt_us, round(1e6 / cfg.imu_rate_hz))
        self.imu_rate_hz = 1e6 / self.imu_interval_us
        ic = sensors.imu
        fast = replace(
            sensors,
            imu=replace(
                ic,
                gyro_noise_density=math.hypot(
                    ic.gyro_noise_density, cfg.broadband_gyro_radps / math.sqrt(self.imu_rate_hz)
                ),
                accel_noise_density=math.hypot(
                    ic.accel_noise_density, cfg.broadband_accel_mps2 / math.sqrt(self.imu_rate_hz)
                ),
            ),
        )
        self.imu_model = ImuModel(fast, r_imu, faults)
        self._next_imu_us = self.imu_interval_us
        # vibration of (accel x, y, z, gyro x, y, z): a sum over rotors r and harmonics h of
        # (Omega_r / Omega_trim)^2 (c_sin sin(h phi_r) + c_cos cos(h phi_r)), i.e. an
        # amplitude and a seeded phase per axis
        trim2 = (
            1.0 / max(rotor_trim_radps[0], 1.0) ** 2,
            1.0 / max(rotor_trim_radps[1], 1.0) ** 2,
        )
        amp = [v * noise for v in (*cfg.vibration_accel_mps2, *cfg.vibration_gyro_radps)]
        # per rotor: (harmonic, coefficients of sin(h phi) for the 6 axes, of cos(h phi))
        vib: list[list[tuple[float, tuple[float, ...], tuple[float, ...]]]] = []
        for _rotor in range(2):
            terms = []
            for h, w in zip(cfg.vibration_harmonics, cfg.vibration_harmonic_weights, strict=True):
                psi = r_vib.uniform(0.0, 2.0 * math.pi, 6).tolist()
                terms.append(
                    (
                        h,
                        tuple(w * a * math.cos(p) for a, p in zip(amp, psi, strict=True)),
                        tuple(w * a * math.sin(p) for a, p in zip(amp, psi, strict=True)),
                    )
                )
            vib.append(terms)
        vib_on = any(v != 0.0 for v in amp) and any(
            w != 0.0 for w in cfg.vibration_harmonic_weights
        )
        #: the fast samples (compiled): the latest in ``gyro_radps``, ``accel_mps2``
        self.fast = FastImu(
            self.imu_model,
            g_mps2,
            self.imu_interval_us,
            v0_ned_mps,
            trim2,
            vib,
            vib_on,
            rotate_ned_to_body(q0, (0.0, 0.0, -g_mps2)),
        )
        # --- attitude estimator
        self.ahrs_interval_us = max(self.imu_interval_us, round(1e6 / cfg.ahrs_rate_hz))
        self._next_ahrs_us = self.ahrs_interval_us
        self.q_est: Quat = q0
        self.euler_est_rad: Vec3 = euler_from_quat(*q0)
        cs = (cfg.gyro_cal_sigma_radps, cfg.accel_cal_sigma_mps2)
        cal = r_cal.standard_normal(6)
        gb, ab = self.imu_model.gyro_bias_radps, self.imu_model.accel_bias_mps2
        self.gyro_bias_est_radps = [gb[i] + cs[0] * bias * float(cal[i]) for i in range(3)]
        #: the accelerometer offset the estimator removes (fixed: its calibration)
        self.accel_cal_mps2: Vec3 = (
            ab[0] + cs[1] * bias * float(cal[3]),
            ab[1] + cs[1] * bias * float(cal[4]),
            ab[2] + cs[1] * bias * float(cal[5]),
        )
        self.compass_bias_rad = cfg.compass_bias_sigma_rad * bias * float(r_cal.standard_normal())
        self._compass_sigma = cfg.compass_noise_rad * noise
        self._r_cal = r_cal
        self.rates_est_radps: Vec3 = (0.0, 0.0, 0.0)
        t_ahrs = self.ahrs_interval_us / 1e6
        fc = cfg.ahrs_rate_filter_hz
        self._k_rate = 1.0 - math.exp(-2.0 * math.pi * fc * t_ahrs)
        # --- GPS and its filter
        self.gps_interval_us = max(dt_us, round(1e6 / cfg.gps_rate_hz))
        t_gps = self.gps_interval_us / 1e6
        self._next_gps_us = self.gps_interval_us
        tau = cfg.velocity_filter_tau_s
        self._k_gps = 1.0 - math.exp(-t_gps / tau) if tau > 0.0 else 1.0
        delay_s = cfg.velocity_lag_s - filter_delay_s(replace(cfg, gps_rate_hz=1.0 / t_gps))
        self.gps_delay_us = max(0, round(delay_s * 1e6))
        self._k_acc = 1.0 - math.exp(-t_gps / max(cfg.ahrs_accel_comp_tau_s, 1e-6))
        self._hist: deque[tuple[int, Vec3, Vec3]] = deque(
            maxlen=self.gps_delay_us // self.imu_interval_us + 4
        )
        self._hist.append((0, p0_ned_m, v0_ned_mps))
        self._sv = cfg.gps_velocity_sigma_mps * noise
        self._sp = cfg.gps_position_sigma_m * noise
        self._r_gps = r_gps
        self.p_filt_ned_m: list[float] = list(p0_ned_m)
        self.v_filt_ned_mps: list[float] = list(v0_ned_mps)
        self.a_gps_ned_mps2: list[float] = [0.0, 0.0, 0.0]
        self._faults = PositionVelocitySensor(replace(sensors, noise=False), r_gps, r_fault, faults)

    # ------------------------------------------------------------------ per step
    def update(self, t_us: int, x: Sequence[float]) -> None:
        """Run whatever is due at ``t_us`` on the state ``x`` (after every physics step)."""
        if t_us < self._next_imu_us:
            return
        self._next_imu_us += self.imu_interval_us
        if self._next_imu_us <= t_us:
            self._next_imu_us = t_us + self.imu_interval_us
        q = (x[6], x[7], x[8], x[9])
        v_ned = rotate_body_to_ned(q, (x[3], x[4], x[5]))
        self.fast.sample(t_us, x[6], x[7], x[8], x[9], v_ned, (x[10], x[11], x[12]), x[13], x[14])
        self._hist.append((t_us, (x[0], x[1], x[2]), v_ned))
        if t_us >= self._next_gps_us:
            self._gps_fix(t_us)
            self._next_gps_us = max(self._next_gps_us + self.gps_interval_us, t_us + 1)
        if t_us >= self._next_ahrs_us:
            self._next_ahrs_us = max(self._next_ahrs_us + self.ahrs_interval_us, t_us + 1)
            self._ahrs(q)

    def _gps_fix(self, t_us: int) -> None:
        t_want = t_us - self.gps_delay_us
        p, v = self._delayed(t_want)
        if self._sv > 0.0 or self._sp > 0.0:
            n = self._r_gps.standard_normal(6)
            p = (
                p[0] + self._sp * float(n[0]),
                p[1] + self._sp * float(n[1]),
                p[2] + self._sp * float(n[2]),
            )
            v = (
                v[0] + self._sv * float(n[3]),
                v[1] + self._sv * float(n[4]),
                v[2] + self._sv * float(n[5]),
            )
        k = self._k_gps
        ka = self._k_acc
        rate = 1e6 / self.gps_interval_us
        pf, vf, af = self.p_filt_ned_m, self.v_filt_ned_mps, self.a_gps_ned_mps2
        for i in range(3):
            pf[i] += k * (p[i] - pf[i])
            dv = k * (v[i] - vf[i])
            vf[i] += dv
            af[i] += ka * (dv * rate - af[i])

    def _delayed(self, t_us: int) -> tuple[Vec3, Vec3]:
        """Truth (position, NED velocity) at ``t_us`` from the history, linear in time."""
        h = self._hist
        if t_us <= h[0][0]:
            return h[0][1], h[0][2]
        # the history is at the fast IMU rate: walk back from the newest entry
        i = len(h) - 1
        while i > 0 and h[i - 1][0] >= t_us:
            i -= 1
        t1, p1, v1 = h[i]
        t0, p0, v0 = h[i - 1] if i > 0 else h[i]
        if t1 == t0 or t_us >= t1:
            return p1, v1
        w = (t_us - t0) / (t1 - t0)
        return (
            (p0[0] + w * (p1[0] - p0[0]), p0[1] + w * (p1[1] - p0[1]), p0[2] + w * (p1[2] - p0[2])),
            (v0[0] + w * (v1[0] - v0[0]), v0[1] + w * (v1[1] - v0[1]), v0[2] + w * (v1[2] - v0[2])),
        )

    def _ahrs(self, q_true: Quat) -> None:
        s, n = self.fast.take_sums()
        if n == 0:
            return
        inv = 1.0 / n
        ac = self.accel_cal_mps2
        fm = (s[0] * inv - ac[0], s[1] * inv - ac[1], s[2] * inv - ac[2])
        b = self.gyro_bias_est_radps
        w = (s[3] * inv - b[0], s[4] * inv - b[1], s[5] * inv - b[2])
        cfg = self.cfg
        t = self.ahrs_interval_us / 1e6
        qe = self.q_est
        a = self.a_gps_ned_mps2
        fp = rotate_ned_to_body(qe, (a[0], a[1], a[2] - self.g_mps2))
        # e = f_m x f_pred / |f_pred|^2: linear in f_m, so zero-mean vibration averages out
        # (normalising by |f_m| too would rectify correlated axes into a tilt bias)
        n2 = fp[0] * fp[0] + fp[1] * fp[1] + fp[2] * fp[2]
        ex = ey = ez = 0.0
        if n2 > 1e-6:  # no tilt reference in free fall
            k = 1.0 / n2
            ex = (fm[1] * fp[2] - fm[2] * fp[1]) * k
            ey = (fm[2] * fp[0] - fm[0] * fp[2]) * k
            ez = (fm[0] * fp[1] - fm[1] * fp[0]) * k
        # compass: the true heading with a constant bias and white noise
        psi_true = euler_from_quat(*q_true)[2]
        psi_m = psi_true + self.compass_bias_rad
        if self._compass_sigma > 0.0:
            psi_m += self._compass_sigma * float(self._r_cal.standard_normal())
        e_psi = _wrap(psi_m - self.euler_est_rad[2])
        d = rotate_ned_to_body(qe, (0.0, 0.0, 1.0))
        kp, ky, ki = cfg.ahrs_tilt_gain, cfg.ahrs_yaw_gain, cfg.ahrs_bias_gain
        wx = w[0] + kp * ex + ky * e_psi * d[0]
        wy = w[1] + kp * ey + ky * e_psi * d[1]
        wz = w[2] + kp * ez + ky * e_psi * d[2]
        b[0] -= ki * ex * t
        b[1] -= ki * ey * t
        b[2] -= ki * ez * t
        # q <- q (x) exp(w T / 2)
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        half = 0.5 * wn * t
        c = math.cos(half)
        sk = math.sin(half) / wn if wn > 1e-12 else 0.5 * t
        dq = (c, wx * sk, wy * sk, wz * sk)
        q0, q1, q2, q3 = qe
        r0, r1, r2, r3 = dq
        nq = (
            q0 * r0 - q1 * r1 - q2 * r2 - q3 * r3,
            q0 * r1 + q1 * r0 + q2 * r3 - q3 * r2,
            q0 * r2 - q1 * r3 + q2 * r0 + q3 * r1,
            q0 * r3 + q1 * r2 - q2 * r1 + q3 * r0,
        )
        norm = 1.0 / math.sqrt(nq[0] ** 2 + nq[1] ** 2 + nq[2] ** 2 + nq[3] ** 2)
        self.q_est = (nq[0] * norm, nq[1] * norm, nq[2] * norm, nq[3] * norm)
        self.euler_est_rad = euler_from_quat(*self.q_est)
        kr = self._k_rate
        re = self.rates_est_radps
        self.rates_est_radps = (
            re[0] + kr * (w[0] - re[0]),
            re[1] + kr * (w[1] - re[1]),
            re[2] + kr * (w[2] - re[2]),
        )

    # ------------------------------------------------ the MAVLink side's sample calls
    def imu_sample(self) -> tuple[Vec3, Vec3]:
        return self.fast.gyro_radps, self.fast.accel_mps2

    def position_sample(self, t_s: float) -> tuple[Vec3, Vec3]:
        pf, vf = self.p_filt_ned_m, self.v_filt_ned_mps
        return self._faults.sample(t_s, (pf[0], pf[1], pf[2]), (vf[0], vf[1], vf[2]))

    @property
    def gps_velocity_sigma_mps(self) -> float:
        return self._sv

    @gps_velocity_sigma_mps.setter
    def gps_velocity_sigma_mps(self, sigma_mps: float) -> None:
        self._sv = sigma_mps

    def set_velocity_faults(self, faults: tuple[Fault, ...]) -> None:
        self._faults.set_faults(faults)


class AutopilotImu:
    """``sim.imu`` in the autopilot profile: the latest fast sample (point sampling)."""

    def __init__(self, s: AutopilotSensors) -> None:
        self._s = s

    def sample(
        self, t_s: float, omega_body_radps: Vec3, f_body_mps2: Vec3, rate_hz: float
    ) -> tuple[Vec3, Vec3]:
        return self._s.imu_sample()


class AutopilotAttitude:
    """``sim.attitude_sensor``: the estimator's Euler angles and filtered rates."""

    def __init__(self, s: AutopilotSensors) -> None:
        self._s = s

    def sample(self, euler_rad: Vec3, omega_body_radps: Vec3, rate_hz: float) -> tuple[Vec3, Vec3]:
        return self._s.euler_est_rad, self._s.rates_est_radps


class AutopilotPosition:
    """``sim.position_sensor``: the filtered GPS output, then the scheduled faults."""

    def __init__(self, s: AutopilotSensors) -> None:
        self._s = s

    def sample(self, t_s: float, p_ned_m: Vec3, v_ned_mps: Vec3) -> tuple[Vec3, Vec3]:
        return self._s.position_sample(t_s)

    @property
    def velocity_sigma_mps(self) -> float:
        """The GPS velocity noise before the filter (a ground station's parameter)."""
        return self._s.gps_velocity_sigma_mps

    def set_velocity_sigma_mps(self, sigma_mps: float) -> None:
        self._s.gps_velocity_sigma_mps = sigma_mps

    def set_faults(self, faults: tuple[Fault, ...]) -> None:
        """Replace the velocity faults (applied after the filter, as in ``ideal``)."""
        self._s.set_velocity_faults(faults)
