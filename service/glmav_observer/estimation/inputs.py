"""One vehicle's held inputs (zero-order hold) and the IMU integrals the FDI builds on.

Between two samples every input is held: the attitude (ATTITUDE), the specific force and
gyro rates (IMU, after despiking) and the velocity measurement. Over each step of length
dt the earth-frame acceleration a = E f + g e_d (V̇ = E Γ, equations.md) is integrated
into

- A = ∫ a dt (the dead reckoning of every axis; its history over ~2 ``LAG_WINDOW_S``
  gives the lag regressor L, the mean acceleration over the last ``LAG_WINDOW_S``),
- B = ∫ E dt (the accelerometer bias regressor, ``fdi_reference.ReferenceFit``),
- C = ∫ (−a_e, a_n, 0) dt (the heading-error regressor, fdi module docstring).

Held measurement. A held y lags the truth by about its age times |V̇|; with
``propagate_held_measurement`` it is carried forward with the IMU instead,
y(t) ≈ y(t_y) + (A(t) − A(t_y)) − (B(t) − B(t_y)) b̂ (docs/design/observer-notes.md measures both).
"""

from __future__ import annotations

import collections
import math

from glmav_observer.estimation.fdi_reference import LAG_WINDOW_S, Integrals
from glmav_observer.frames import rotate_flat

Vec3 = tuple[float, float, float]


class HeldInputs:
    """The held samples and the integrals A, B, C of one vehicle (module docstring)."""

    def __init__(self, g_mps2: float) -> None:
        self.g_mps2 = g_mps2
        self.euler_rad: Vec3 | None = None
        self.omega_att_radps: Vec3 = (0.0, 0.0, 0.0)
        self.omega_imu_radps: Vec3 | None = None
        self.f_body_mps2: Vec3 | None = None
        #: the held velocity measurement (NED, m/s; lag-compensated by the caller)
        self.y_ned_mps: list[float] = [math.nan] * 3
        self.a_int: list[float] = [0.0, 0.0, 0.0]
        #: (t, A n, A e, A d) of the last ~2 LAG_WINDOW_S: the lag regressor L (fdi)
        self._a_hist: collections.deque[tuple[float, float, float, float]] = collections.deque()
        self._a_int_at_y: list[float] = [0.0, 0.0, 0.0]
        self._b_int: list[float] = [0.0] * 9
        self._b_int_at_y: list[float] = [0.0] * 9
        self.c_int: list[float] = [0.0, 0.0, 0.0]
        #: ∫ f dt (body) and ∫ dt, and their values at the held measurement: the mean
        #: specific force over a measurement interval (the drag model's input)
        self._f_int: list[float] = [0.0, 0.0, 0.0, 0.0]
        self._f_int_at_y: list[float] = [0.0, 0.0, 0.0, 0.0]

    @property
    def ready(self) -> bool:
        """Attitude and specific force known: the bank can step."""
        return self.euler_rad is not None and self.f_body_mps2 is not None

    def omega_radps(self) -> Vec3:
        """The body rates: the IMU's gyro once one came, else ATTITUDE's."""
        return self.omega_imu_radps if self.omega_imu_radps is not None else self.omega_att_radps

    def y_for_step(self, bias_body_mps2: Vec3, propagate: bool) -> list[float]:
        """The measurement the bank is corrected with over the next step: the held y, or
        y(t_y) + ΔA − ΔB b̂ with ``propagate`` (module docstring)."""
        y = self.y_ned_mps
        if not propagate:
            return y
        b0, b1, b2 = bias_body_mps2
        bi, by = self._b_int, self._b_int_at_y
        ai, ay = self.a_int, self._a_int_at_y
        # y_i + ΔA_i − Σ_k ΔB_ik b_k, row by row (the same sums in the same order)
        return [
            y[0]
            + (ai[0] - ay[0])
            - ((bi[0] - by[0]) * b0 + (bi[1] - by[1]) * b1 + (bi[2] - by[2]) * b2),
            y[1]
            + (ai[1] - ay[1])
            - ((bi[3] - by[3]) * b0 + (bi[4] - by[4]) * b1 + (bi[5] - by[5]) * b2),
            y[2]
            + (ai[2] - ay[2])
            - ((bi[6] - by[6]) * b0 + (bi[7] - by[7]) * b1 + (bi[8] - by[8]) * b2),
        ]

    def integrate(self, t: float, dt: float, e_flat: list[float]) -> None:
        """Advance A, its history, C and B over [t − dt, t] with E = ``e_flat`` (row-major)
        held."""
        assert self.f_body_mps2 is not None
        f = self.f_body_mps2
        a = rotate_flat(e_flat, f)  # E Γ = E f + g e_d (V̇ = E Γ)
        a_n_dt = a[0] * dt
        a_e_dt = a[1] * dt
        ai = self.a_int
        ai[0] += a_n_dt
        ai[1] += a_e_dt
        ai[2] += (a[2] + self.g_mps2) * dt
        hist = self._a_hist
        hist.append((t, ai[0], ai[1], ai[2]))
        while len(hist) > 2 and hist[1][0] <= t - LAG_WINDOW_S:
            hist.popleft()
        # C = ∫ (−a_e, a_n, 0) dt: the heading-error regressor (fdi module docstring)
        c = self.c_int
        c[0] -= a_e_dt
        c[1] += a_n_dt
        # B = ∫ E dt (ReferenceFit), entry by entry
        e0, e1, e2, e3, e4, e5, e6, e7, e8 = e_flat
        bi = self._b_int
        bi[0] += e0 * dt
        bi[1] += e1 * dt
        bi[2] += e2 * dt
        bi[3] += e3 * dt
        bi[4] += e4 * dt
        bi[5] += e5 * dt
        bi[6] += e6 * dt
        bi[7] += e7 * dt
        bi[8] += e8 * dt
        fi = self._f_int
        fi[0] += f[0] * dt
        fi[1] += f[1] * dt
        fi[2] += f[2] * dt
        fi[3] += dt

    def hold_measurement(self, y_ned_mps: list[float]) -> None:
        """Hold a new measurement from now on (the propagation restarts from here)."""
        self.y_ned_mps = y_ned_mps
        self._a_int_at_y = list(self.a_int)
        self._b_int_at_y = list(self._b_int)
        self._f_int_at_y = list(self._f_int)

    def f_mean_since_measurement(self) -> Vec3 | None:
        """The mean body-frame specific force (m/s²) since the held measurement; None
        before any step since it."""
        fi, f0 = self._f_int, self._f_int_at_y
        span = fi[3] - f0[3]
        if span <= 0.0:
            return None
        return ((fi[0] - f0[0]) / span, (fi[1] - f0[1]) / span, (fi[2] - f0[2]) / span)

    def ints(self) -> Integrals:
        """(B, C, L): the integrals the FDI's regressors are built from; L the mean
        earth-frame acceleration over the last LAG_WINDOW_S (A's difference)."""
        c = self.c_int
        hist = self._a_hist
        ai = self.a_int
        l_now = (0.0, 0.0, 0.0)
        if len(hist) >= 2:
            t0, *a0 = hist[0]
            span = hist[-1][0] - t0
            if span > 0.0:
                l_now = ((ai[0] - a0[0]) / span, (ai[1] - a0[1]) / span, (ai[2] - a0[2]) / span)
        return tuple(self._b_int), (c[0], c[1], c[2]), l_now
