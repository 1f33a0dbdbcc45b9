"""One vehicle's held inputs (zero-order hold) and the IMU integrals the FDI builds on.

Compiled (Cython; the per-sample core): :meth:`HeldInputs.integrate` runs at every step
of the bank (the IMU's and the attitude's rates together).

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

Trapezoidal IMU. The step holds the last specific force f_{k−1} until the next IMU
sample; when f_k comes at t_k, :meth:`BankCore.centre_imu` adds (f_k − f_{k−1}) Δt/2 over
the IMU interval Δt, so that at every IMU sample the integrals and states are the
trapezoid's, ∫ a dt over [t_{k−1}, t_k] ≈ (a_{k−1} + a_k) Δt/2: a held f lags the
samples by Δt/2 (20 ms at a 25 Hz IMU; docs/design/observer-notes.md, "Trapezoidal IMU").

Every sum is the former Python code's, in its order (setup.py: no fused multiply-add).
"""

from libc.stdlib cimport free, malloc
from libc.string cimport memcpy

from glmav_observer.rotation cimport e_flat_c, load3, rotate_c

from glmav_observer.estimation.fdi_reference import LAG_WINDOW_S as _LAG_WINDOW_S

cdef double LAG_WINDOW = _LAG_WINDOW_S

cdef class HeldInputs:
    """The held samples and the integrals A, B, C of one vehicle (module docstring)."""

    # attributes: inputs.pxd (the held samples as they came, tuples of three floats or
    # None; y, A, A at y, B, B at y, C; ∫ f dt and ∫ dt and their values at y, the mean
    # specific force over a measurement interval (the drag model's input); the history
    # (t, A n, A e, A d) of the last ~2 LAG_WINDOW_S as a ring, for the lag regressor L)

    def __cinit__(self, double g_mps2):
        self.h_cap = 64
        self.hist = <double*> malloc(self.h_cap * 4 * sizeof(double))
        if self.hist == NULL:
            raise MemoryError()
        self.h_start = 0
        self.h_len = 0

    def __dealloc__(self):
        free(self.hist)

    def __init__(self, double g_mps2):
        self.g_mps2 = g_mps2
        self.euler_rad = None
        self.omega_att_radps = (0.0, 0.0, 0.0)
        self.omega_imu_radps = None
        self.f_body_mps2 = None
        cdef int k
        for k in range(3):
            self.y[k] = float("nan")
            self.a_int_c[k] = 0.0
            self.a_at_y[k] = 0.0
            self.c_int_c[k] = 0.0
        for k in range(9):
            self.b_int[k] = 0.0
            self.b_at_y[k] = 0.0
        for k in range(4):
            self.f_int[k] = 0.0
            self.f_at_y[k] = 0.0

    # ------------------------------------------------------------------ copy / pickle
    def __reduce__(self):
        """The held samples and the integrals (for copy.deepcopy and pickle)."""
        cdef Py_ssize_t i
        hist = [tuple(self._hist_at(i)[k] for k in range(4)) for i in range(self.h_len)]
        state = (
            self.euler_rad, self.omega_att_radps, self.omega_imu_radps, self.f_body_mps2,
            [self.y[k] for k in range(3)], [self.a_int_c[k] for k in range(3)],
            [self.a_at_y[k] for k in range(3)], [self.b_int[k] for k in range(9)],
            [self.b_at_y[k] for k in range(9)], [self.c_int_c[k] for k in range(3)],
            [self.f_int[k] for k in range(4)], [self.f_at_y[k] for k in range(4)], hist,
        )
        return (HeldInputs, (self.g_mps2,), state)

    def __setstate__(self, state):
        cdef Py_ssize_t k
        (self.euler_rad, self.omega_att_radps, self.omega_imu_radps, self.f_body_mps2,
         y, a, ay, b, by, c, fi, fy, hist) = state
        for k in range(3):
            self.y[k] = y[k]
            self.a_int_c[k] = a[k]
            self.a_at_y[k] = ay[k]
            self.c_int_c[k] = c[k]
        for k in range(9):
            self.b_int[k] = b[k]
            self.b_at_y[k] = by[k]
        for k in range(4):
            self.f_int[k] = fi[k]
            self.f_at_y[k] = fy[k]
        cdef double row[3]
        self.h_start = 0
        self.h_len = 0
        for t, a0, a1, a2 in hist:
            row[0] = a0
            row[1] = a1
            row[2] = a2
            self._hist_push(t, row)

    @property
    def y_ned_mps(self):
        """The held velocity measurement (NED, m/s; lag-compensated by the caller)."""
        return [self.y[0], self.y[1], self.y[2]]

    @property
    def a_int(self):
        """A = ∫ a dt, NED, m/s (a copy)."""
        return [self.a_int_c[0], self.a_int_c[1], self.a_int_c[2]]

    @property
    def c_int(self):
        """C = ∫ (−a_e, a_n, 0) dt, m/s (a copy)."""
        return [self.c_int_c[0], self.c_int_c[1], self.c_int_c[2]]

    @property
    def ready(self):
        """Attitude and specific force known: the bank can step."""
        return self.euler_rad is not None and self.f_body_mps2 is not None

    def omega_radps(self):
        """The body rates: the IMU's gyro once one came, else ATTITUDE's."""
        return self.omega_imu_radps if self.omega_imu_radps is not None else self.omega_att_radps

    cdef void y_for_step_c(self, const double* b, bint propagate, double* out) noexcept:
        cdef const double* bi = self.b_int
        cdef const double* by = self.b_at_y
        cdef const double* ai = self.a_int_c
        cdef const double* ay = self.a_at_y
        cdef double b0 = b[0], b1 = b[1], b2 = b[2]
        if not propagate:
            memcpy(out, self.y, 3 * sizeof(double))
            return
        # y_i + ΔA_i − Σ_k ΔB_ik b_k, row by row
        out[0] = self.y[0] + (ai[0] - ay[0]) - (
            (bi[0] - by[0]) * b0 + (bi[1] - by[1]) * b1 + (bi[2] - by[2]) * b2)
        out[1] = self.y[1] + (ai[1] - ay[1]) - (
            (bi[3] - by[3]) * b0 + (bi[4] - by[4]) * b1 + (bi[5] - by[5]) * b2)
        out[2] = self.y[2] + (ai[2] - ay[2]) - (
            (bi[6] - by[6]) * b0 + (bi[7] - by[7]) * b1 + (bi[8] - by[8]) * b2)

    def y_for_step(self, bias_body_mps2, bint propagate):
        """The measurement the bank is corrected with over the next step: the held y, or
        y(t_y) + ΔA − ΔB b̂ with ``propagate`` (module docstring)."""
        cdef double b[3]
        cdef double out[3]
        load3(bias_body_mps2, b)
        self.y_for_step_c(b, propagate, out)
        return [out[0], out[1], out[2]]

    cdef void y_rate_c(self, const double* E, const double* f, const double* b, double* out) noexcept:
        """The rate of :meth:`y_for_step`'s propagated measurement over a step with the
        attitude's E and the specific force ``f`` held: d/dt (ΔA − ΔB b̂) = E (f − b̂) + g e_d
        (NED, m/s²; the bank's ramp, observer.zoh_step's ``y_rate_ned_mps2``)."""
        cdef double fr[3]
        fr[0] = f[0] - b[0]
        fr[1] = f[1] - b[1]
        fr[2] = f[2] - b[2]
        rotate_c(E, fr, out)
        out[2] += self.g_mps2

    def y_rate(self, bias_body_mps2):
        """:meth:`y_rate_c` at the held attitude and specific force (both must be held)."""
        cdef double E[9]
        cdef double f[3]
        cdef double b[3]
        cdef double out[3]
        phi, theta, psi = self.euler_rad
        e_flat_c(phi, theta, psi, E)
        load3(self.f_body_mps2, f)
        load3(bias_body_mps2, b)
        self.y_rate_c(E, f, b, out)
        return [out[0], out[1], out[2]]

    cdef void _hist_push(self, double t, const double* ai) except *:
        cdef Py_ssize_t i, n
        cdef double* grown
        if self.h_len == self.h_cap:  # grow, unrolling the ring
            grown = <double*> malloc(2 * self.h_cap * 4 * sizeof(double))
            if grown == NULL:
                raise MemoryError()
            for i in range(self.h_len):
                memcpy(&grown[4 * i], &self.hist[4 * ((self.h_start + i) % self.h_cap)],
                       4 * sizeof(double))
            free(self.hist)
            self.hist = grown
            self.h_cap *= 2
            self.h_start = 0
        n = (self.h_start + self.h_len) % self.h_cap
        self.hist[4 * n] = t
        self.hist[4 * n + 1] = ai[0]
        self.hist[4 * n + 2] = ai[1]
        self.hist[4 * n + 3] = ai[2]
        self.h_len += 1

    cdef double* _hist_at(self, Py_ssize_t i) noexcept:
        return &self.hist[4 * ((self.h_start + i) % self.h_cap)]

    cdef void integrate_c(self, double t, double dt, const double* E, const double* f) except *:
        cdef double a[3]
        cdef double* ai = self.a_int_c
        cdef double* bi = self.b_int
        cdef double* fi = self.f_int
        rotate_c(E, f, a)  # E Γ = E f + g e_d (V̇ = E Γ)
        cdef double a_n_dt = a[0] * dt
        cdef double a_e_dt = a[1] * dt
        ai[0] += a_n_dt
        ai[1] += a_e_dt
        ai[2] += (a[2] + self.g_mps2) * dt
        self._hist_push(t, ai)
        while self.h_len > 2 and self._hist_at(1)[0] <= t - LAG_WINDOW:
            self.h_start = (self.h_start + 1) % self.h_cap
            self.h_len -= 1
        # C = ∫ (−a_e, a_n, 0) dt: the heading-error regressor (fdi module docstring)
        self.c_int_c[0] -= a_e_dt
        self.c_int_c[1] += a_n_dt
        # B = ∫ E dt (ReferenceFit), entry by entry
        cdef int k
        for k in range(9):
            bi[k] += E[k] * dt
        fi[0] += f[0] * dt
        fi[1] += f[1] * dt
        fi[2] += f[2] * dt
        fi[3] += dt

    cdef void kick_c(self, const double* E, const double* d_body) noexcept:
        """Add the trapezoid's correction to the integrals: ``d_body`` = (f_k − f_{k−1})
        Δt/2 in the body frame (m/s), rotated by E into A and C; ∫ f dt takes it as it is
        (BankCore.centre_imu)."""
        cdef double d[3]
        rotate_c(E, d_body, d)
        self.a_int_c[0] += d[0]
        self.a_int_c[1] += d[1]
        self.a_int_c[2] += d[2]
        self.c_int_c[0] -= d[1]
        self.c_int_c[1] += d[0]
        self.f_int[0] += d_body[0]
        self.f_int[1] += d_body[1]
        self.f_int[2] += d_body[2]

    def integrate(self, double t, double dt, e_flat):
        """Advance A, its history, C and B over [t − dt, t] with E = ``e_flat`` (row-major)
        held."""
        cdef double E[9]
        cdef double f[3]
        cdef int k
        assert self.f_body_mps2 is not None
        for k in range(9):
            E[k] = e_flat[k]
        load3(self.f_body_mps2, f)
        self.integrate_c(t, dt, E, f)

    def hold_measurement(self, y_ned_mps):
        """Hold a new measurement from now on (the propagation restarts from here)."""
        load3(y_ned_mps, self.y)
        memcpy(self.a_at_y, self.a_int_c, 3 * sizeof(double))
        memcpy(self.b_at_y, self.b_int, 9 * sizeof(double))
        memcpy(self.f_at_y, self.f_int, 4 * sizeof(double))

    def f_mean_since_measurement(self):
        """The mean body-frame specific force (m/s²) since the held measurement; None
        before any step since it."""
        cdef double* fi = self.f_int
        cdef double* f0 = self.f_at_y
        cdef double span = fi[3] - f0[3]
        if span <= 0.0:
            return None
        return ((fi[0] - f0[0]) / span, (fi[1] - f0[1]) / span, (fi[2] - f0[2]) / span)

    def ints(self):
        """(B, C, L): the integrals the FDI's regressors are built from; L the mean
        earth-frame acceleration over the last LAG_WINDOW_S (A's difference)."""
        cdef double* ai = self.a_int_c
        cdef double* h0
        cdef double span
        l_now = (0.0, 0.0, 0.0)
        if self.h_len >= 2:
            h0 = self._hist_at(0)
            span = self._hist_at(self.h_len - 1)[0] - h0[0]
            if span > 0.0:
                l_now = ((ai[0] - h0[1]) / span, (ai[1] - h0[2]) / span, (ai[2] - h0[3]) / span)
        b = self.b_int
        return (
            (b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8]),
            (self.c_int_c[0], self.c_int_c[1], self.c_int_c[2]),
            l_now,
        )
