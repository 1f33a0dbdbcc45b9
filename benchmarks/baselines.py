"""The alternatives the observer bank is measured against, fed the same inputs as the bank.

All three estimate the earth-frame (NED) velocity V from the same held inputs the
service's estimator steps its bank with: the attitude (ATTITUDE), the accelerometer's
specific force f (IMU) and the measured velocity y (LOCAL_POSITION_NED), and each sees the
same NED axes as the configuration it stands beside (the bank's ``last_meas_mask``: the
configuration's C_i, minus axes the FDI rejected, minus missing axes).

- :class:`KalmanVelocity`: the linear Kalman filter a Python user would build with
  ``filterpy``: state V (3), prediction V̇ = E Γ = E f + g e_d (equations.md, "What careful
  analysis adds"), process noise from the accelerometer's white-noise density
  (Q = q² Δt I, q = 4e-3 m/s²/√Hz, design.md), measurement H = the measured rows of I,
  R = σ² I with σ = 0.05 m/s; a measurement is applied when it arrives.
- :class:`DeadReckoning`: V integrated from E f + g e_d alone, from the first measurement.
- :class:`RawMeasurement`: the last measured value of each axis, held (an axis never
  measured keeps the first measurement).

Frames: NED earth, FRD body, ZYX Euler (MAVLink); SI units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from glmav_observer.estimation.observer import G_MPS2

FloatArray = NDArray[np.float64]

#: design.md sensor defaults: accelerometer white-noise density, velocity noise per sample.
ACCEL_NOISE_DENSITY = 4e-3  # m/s²/√Hz
SIGMA_MEAS_MPS = 0.05


def earth_accel_mps2(euler_rad: Sequence[float], f_body_mps2: Sequence[float]) -> FloatArray:
    """a = E Γ = E f + (0, 0, g): the earth-frame acceleration (V̇ = E Γ; Γ = f + g_body (9)),
    E the exact body-to-earth matrix (13), written out in floats (called at the IMU rate)."""
    phi, th, psi = euler_rad
    f0, f1, f2 = f_body_mps2
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(th), math.cos(th)
    sp, cp = math.sin(psi), math.cos(psi)
    return np.array(
        [
            ct * cp * f0 + (sf * st * cp - cf * sp) * f1 + (cf * st * cp + sf * sp) * f2,
            ct * sp * f0 + (sf * st * sp + cf * cp) * f1 + (cf * st * sp - sf * cp) * f2,
            -st * f0 + sf * ct * f1 + cf * ct * f2 + G_MPS2,
        ]
    )


class KalmanVelocity:
    """filterpy ``KalmanFilter`` on V_ned (3 states); see the module docstring."""

    def __init__(
        self,
        v0_ned_mps: Sequence[float],
        p0_mps2: float = SIGMA_MEAS_MPS**2,
        accel_noise_density: float = ACCEL_NOISE_DENSITY,
        sigma_meas_mps: float = SIGMA_MEAS_MPS,
    ) -> None:
        from filterpy.kalman import KalmanFilter

        self.kf = KalmanFilter(dim_x=3, dim_z=3)
        self.kf.x = np.asarray(v0_ned_mps, dtype=np.float64).reshape(3, 1).copy()
        self.kf.P = np.eye(3) * p0_mps2
        self.kf.F = np.eye(3)
        self.q2 = accel_noise_density**2  # m²/s³
        self.r2 = sigma_meas_mps**2
        self._eye = np.eye(3)

    @property
    def v_ned_mps(self) -> FloatArray:
        out: FloatArray = self.kf.x[:, 0].copy()
        return out

    def predict(self, dt_s: float, a_ned_mps2: FloatArray) -> None:
        """V ← V + a Δt, P ← P + q² Δt I."""
        if dt_s <= 0.0:
            return
        self.kf.predict(
            u=a_ned_mps2.reshape(3, 1), B=self._eye * dt_s, Q=self._eye * (self.q2 * dt_s)
        )

    def update(self, y_ned_mps: Sequence[float], mask: Sequence[bool]) -> None:
        """Measurement of the axes in ``mask`` that are finite in ``y``."""
        idx = [i for i in range(3) if mask[i] and math.isfinite(y_ned_mps[i])]
        if not idx:
            return
        H = self._eye[idx]
        z = np.asarray([y_ned_mps[i] for i in idx]).reshape(-1, 1)
        self.kf.update(z, R=np.eye(len(idx)) * self.r2, H=H)


class DeadReckoning:
    """V integrated from the earth-frame acceleration only."""

    def __init__(self, v0_ned_mps: Sequence[float]) -> None:
        self.v = np.asarray(v0_ned_mps, dtype=np.float64).copy()

    @property
    def v_ned_mps(self) -> FloatArray:
        return self.v.copy()

    def predict(self, dt_s: float, a_ned_mps2: FloatArray) -> None:
        if dt_s > 0.0:
            self.v += a_ned_mps2 * dt_s

    def update(self, y_ned_mps: Sequence[float], mask: Sequence[bool]) -> None:
        """Dead reckoning ignores measurements."""


class RawMeasurement:
    """The last measured value of each axis (held)."""

    def __init__(self, v0_ned_mps: Sequence[float]) -> None:
        self.v = np.asarray(v0_ned_mps, dtype=np.float64).copy()

    @property
    def v_ned_mps(self) -> FloatArray:
        return self.v.copy()

    def predict(self, dt_s: float, a_ned_mps2: FloatArray) -> None:
        """The raw measurement does not use the IMU."""

    def update(self, y_ned_mps: Sequence[float], mask: Sequence[bool]) -> None:
        for i in range(3):
            if mask[i] and math.isfinite(y_ned_mps[i]):
                self.v[i] = y_ned_mps[i]


Baseline = KalmanVelocity | DeadReckoning | RawMeasurement
