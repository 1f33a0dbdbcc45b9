"""The bank's per-sample step in C: every configuration's exact zero-order-hold update.

Compiled (Cython): :class:`BankCore` holds one vehicle's four states x̂ (body FRD, m/s)
and the E of its last step, and advances them with the closed form of
:func:`~glmav_observer.estimation.observer.zoh_earth` for the exact E (13) and two or
three measured axes per configuration (docs/design/observer-notes.md, "Discrete-time
update"). :class:`~glmav_observer.estimation.bank.ObserverBank` is its Python face (and
keeps the numpy form for the other cases); the numpy :mod:`.observer` is the oracle
tests/unit/glmav_observer/estimation/test_bank.py pins it to (1e-12).

With ``propagate_held_measurement`` the measurement the states are pulled to moves over
the step, y(τ) = y + ρ τ with ρ = E (f − b̂) + g e_d (inputs.HeldInputs.y_for_step):
the ramp terms of :func:`~glmav_observer.estimation.observer.zoh_earth` take it. A held y
lags by half a step in the state (docs/design/observer-notes.md, "The measurement's ramp").

Sums in the former plain-float code's order (setup.py: no fused multiply-add).
"""

from libc.math cimport exp, expm1, isfinite

from glmav_observer.estimation.inputs cimport HeldInputs
from glmav_observer.rotation cimport e_flat_c, load3, rotate_c, rotate_t_c

#: Below this |γ·Δt| the φ-functions use their Taylor series (no cancellation); 9 terms:
#: the first neglected one is < 0.1⁹/9! ≈ 3e-15 relative (observer.phi1_phi2).
cdef double PHI_SERIES_BELOW = 0.1
#: Step lengths whose φ-terms are kept: a vehicle's steps take a few lengths (IMU 250 Hz,
#: ATTITUDE 100 Hz: 1 to 4 ms), each with a few float round-offs of a time difference (on
#: the simulator's stream 40 distinct lengths, 99 % of steps among the last 16).
cdef enum:
    TERMS_CACHE = 16

cdef double[11] INV_FACT
INV_FACT[:] = [1.0, 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0, 1.0 / 5040.0,
               1.0 / 40320.0, 1.0 / 362880.0, 1.0 / 3628800.0]


cdef void phi12(double x, double* p1, double* p2) noexcept nogil:
    """φ1(x) = (eˣ − 1)/x and φ2(x) = (eˣ − 1 − x)/x², accurate for x ≤ 0."""
    cdef const double* f = INV_FACT
    if -PHI_SERIES_BELOW < x < PHI_SERIES_BELOW:  # the 9-term Taylor polynomials (Horner)
        p1[0] = f[1] + x * (f[2] + x * (f[3] + x * (f[4] + x * (f[5] + x * (f[6] + x * (
            f[7] + x * (f[8] + x * f[9])))))))
        p2[0] = f[2] + x * (f[3] + x * (f[4] + x * (f[5] + x * (f[6] + x * (f[7] + x * (
            f[8] + x * (f[9] + x * f[10])))))))
        return
    p1[0] = expm1(x) / x
    p2[0] = (p1[0] - 1.0) / x


cdef class BankCore:
    """Four configurations' states and the E of the last step (module docstring)."""

    cdef double x[4][3]
    cdef double E[9]
    cdef double gam[4]
    cdef public double g_mps2
    # φ-terms (e^{−γh}, h φ1(−γh), h² φ2(−γh)) per configuration, by step length h
    cdef double cache_h[TERMS_CACHE]
    cdef double cache_terms[TERMS_CACHE][4][3]
    cdef int n_cached, next_slot
    # each configuration's own lost axis (−1: none; configurations.CONFIGURATIONS)
    cdef int config_lost[4]
    # the lost axis each configuration had in the last fused step (advance)
    cdef int last_lost[4]
    # `full`'s measurement compared in the step's frame (EstimatorConfig.
    # rotate_measurement): its ramp takes −ω_e × y
    cdef public bint rotate_y
    # the accelerometer's filter delay taken out at each IMU sample (centre_imu), s
    cdef public double imu_lead_s

    def __init__(self, gammas, double g_mps2, config_lost=(-1, 0, 1, 2),
                 bint rotate_y=False, double imu_lead_s=0.0):
        cdef int i, k
        self.g_mps2 = g_mps2
        self.rotate_y = rotate_y
        self.imu_lead_s = imu_lead_s
        for i in range(4):
            self.config_lost[i] = config_lost[i]
            self.last_lost[i] = config_lost[i]
        self.set_gammas(gammas)
        for i in range(4):
            for k in range(3):
                self.x[i][k] = 0.0
        for k in range(9):
            self.E[k] = 1.0 if k % 4 == 0 else 0.0

    def set_gammas(self, gammas):
        """γ per configuration (CONFIGS order); the φ-terms kept are dropped."""
        cdef int i
        if len(gammas) != 4:
            raise ValueError(f"4 gains expected, got {len(gammas)}")
        for i in range(4):
            self.gam[i] = gammas[i]
        self.n_cached = 0
        self.next_slot = 0

    # ------------------------------------------------------------------ state access
    def rows(self):
        """The four states, body frame, as lists of three floats (new lists)."""
        cdef int i
        return [[self.x[i][0], self.x[i][1], self.x[i][2]] for i in range(4)]

    def set_row(self, int i, v):
        """Configuration ``i``'s state (three floats)."""
        if not 0 <= i < 4:
            raise IndexError(i)
        self.x[i][0], self.x[i][1], self.x[i][2] = v

    def set_rows(self, rows):
        """Every state (four rows of three floats)."""
        cdef int i
        if len(rows) != 4:
            raise ValueError(f"4 rows expected, got {len(rows)}")
        for i in range(4):
            self.x[i][0], self.x[i][1], self.x[i][2] = rows[i]

    def ned_rows(self):
        """E x̂ of each configuration under the last step's E, as tuples (matmul's order)."""
        cdef int i
        cdef double n[3]
        out = []
        for i in range(4):
            rotate_c(self.E, &self.x[i][0], n)
            out.append((n[0], n[1], n[2]))
        return out

    def e_list(self):
        """The last step's E, flat row-major (a new list)."""
        cdef double* E = self.E
        return [E[0], E[1], E[2], E[3], E[4], E[5], E[6], E[7], E[8]]

    def set_e_list(self, e_flat):
        """Set E (nine floats, flat row-major)."""
        cdef int k
        if len(e_flat) != 9:
            raise ValueError(f"E: expected 9 entries, got {len(e_flat)}")
        for k in range(9):
            self.E[k] = e_flat[k]

    def set_attitude(self, double phi_rad, double theta_rad, double psi_rad):
        """E from ZYX Euler angles (13)."""
        e_flat_c(phi_rad, theta_rad, psi_rad, self.E)

    def centre_imu(self, HeldInputs inputs, f_new, double dt_imu_s):
        """The trapezoid's correction at an IMU sample (inputs module docstring): every
        state (body frame) and the integrals A, C, ∫ f dt take (f_k − f_{k−1}) (Δt/2 + τ),
        with f_{k−1} the held specific force, f_k = ``f_new``, Δt = ``dt_imu_s`` the IMU's
        interval and τ = ``imu_lead_s`` the accelerometer filter's delay (imu_filter: the
        change is taken τ earlier, v(t) ≈ ∫ f_filtered + τ f_filtered(t)); A and C rotated
        with the last step's E. Nothing without a held f, for Δt ≤ 0 or for a non-finite
        difference."""
        cdef double d[3]
        cdef double fn[3]
        cdef double fo[3]
        cdef int i, k
        if inputs.f_body_mps2 is None or not dt_imu_s > 0.0:
            return
        load3(f_new, fn)
        load3(inputs.f_body_mps2, fo)
        for k in range(3):
            d[k] = (fn[k] - fo[k]) * (0.5 * dt_imu_s + self.imu_lead_s)
            if not isfinite(d[k]):
                return
        for i in range(4):
            for k in range(3):
                self.x[i][k] += d[k]
        inputs.kick_c(self.E, d)

    def lost(self):
        """The unmeasured axis of each configuration in the last :meth:`advance` (−1: none)."""
        return [self.last_lost[0], self.last_lost[1], self.last_lost[2], self.last_lost[3]]

    # ------------------------------------------------------------------ the step
    def advance(self, double t, double dt, HeldInputs inputs, bias_body_mps2, bint propagate,
                b_obs, use):
        """One step of the per-sample path from the held inputs, and their integrals.

        Every configuration over ``dt`` s with the held attitude, body rates (the IMU's,
        else ATTITUDE's), specific force minus ``b_obs`` (the bank's bias, None: none) and
        the held measurement (propagated with ``bias_body_mps2`` when ``propagate``:
        :meth:`HeldInputs.y_for_step`), axes allowed by ``use`` (three bools) and finite;
        then the IMU integrals over the step (:meth:`HeldInputs.integrate`).
        False, with nothing changed, where the numpy path must step instead
        (:meth:`ObserverBank.step_floats`): a configuration with fewer than two measured
        axes, a non-finite input or a negative ``dt``."""
        cdef double eul[3]
        cdef double w[3]
        cdef double f[3]
        cdef double fb[3]
        cdef double y[3]
        cdef double b[3]
        cdef bint ok[3]
        cdef int lost[4]
        cdef int i, k, n, l_
        eul[0], eul[1], eul[2] = inputs.euler_rad
        om = inputs.omega_imu_radps
        w[0], w[1], w[2] = om if om is not None else inputs.omega_att_radps
        f[0], f[1], f[2] = inputs.f_body_mps2
        if b_obs is None:
            fb[0], fb[1], fb[2] = f[0], f[1], f[2]
        else:
            fb[0], fb[1], fb[2] = b_obs
            fb[0] = f[0] - fb[0]
            fb[1] = f[1] - fb[1]
            fb[2] = f[2] - fb[2]
        if not isfinite(dt + eul[0] + eul[1] + eul[2] + w[0] + w[1] + w[2] + fb[0] + fb[1]
                        + fb[2]) or dt < 0.0:
            return False
        b[0], b[1], b[2] = bias_body_mps2
        inputs.y_for_step_c(b, propagate, y)
        ok[0], ok[1], ok[2] = use
        for k in range(3):
            ok[k] = ok[k] and isfinite(y[k])
        for i in range(4):
            n = 0
            l_ = -1
            for k in range(3):
                if k != self.config_lost[i] and ok[k]:
                    n += 1
                else:
                    l_ = k
            if n < 2:
                return False
            lost[i] = l_ if n == 2 else -1
        # the propagated measurement moves at E (f − b̂) + g e_d over the step (y_for_step)
        cdef double rho[3]
        e_flat_c(eul[0], eul[1], eul[2], self.E)
        if propagate:
            inputs.y_rate_c(self.E, f, b, rho)
        self.step_c(dt, w, fb, y, lost, rho if propagate else NULL)
        for i in range(4):
            self.last_lost[i] = lost[i]
        inputs.integrate_c(t, dt, self.E, f)
        return True

    cdef double* _terms(self, double h) noexcept:
        cdef int i, s
        cdef double xg, p1, p2
        for s in range(self.n_cached):
            if self.cache_h[s] == h:
                return &self.cache_terms[s][0][0]
        s = self.next_slot
        self.next_slot = (s + 1) % TERMS_CACHE
        if self.n_cached < TERMS_CACHE:
            self.n_cached += 1
        self.cache_h[s] = h
        for i in range(4):
            xg = -self.gam[i] * h
            phi12(xg, &p1, &p2)
            self.cache_terms[s][i][0] = exp(xg)
            self.cache_terms[s][i][1] = h * p1
            self.cache_terms[s][i][2] = h * h * p2
        return &self.cache_terms[s][0][0]

    def step(self, double h, eul, w, f, y, lost, y_rate=None):
        """Every configuration over ``h`` s, exact E, two or three measured axes each.

        ``eul`` ZYX Euler angles (rad), ``w`` body rates (rad/s), ``f`` the specific force
        (m/s², FRD), ``y`` the measurement (NED, m/s; only measured axes are read, they are
        finite), ``lost[i]`` configuration i's unmeasured axis (−1: none), ``y_rate`` the
        measurement's rate over the step (NED, m/s²; None: held). The caller checked the
        inputs (:meth:`ObserverBank.step_floats`)."""
        cdef double wb[3]
        cdef double fb[3]
        cdef double yv[3]
        cdef double rho[3]
        cdef int ls[4]
        phi, th, psi = eul
        e_flat_c(phi, th, psi, self.E)
        wb[0], wb[1], wb[2] = w
        fb[0], fb[1], fb[2] = f
        yv[0], yv[1], yv[2] = y
        ls[0], ls[1], ls[2], ls[3] = lost
        if y_rate is None:
            self.step_c(h, wb, fb, yv, ls, NULL)
        else:
            rho[0], rho[1], rho[2] = y_rate
            self.step_c(h, wb, fb, yv, ls, rho)

    cdef void step_c(self, double h, const double* w, const double* f, const double* y,
                     const int* lost, const double* rho) noexcept:
        """The step under ``self.E`` (set by the caller from the step's attitude);
        ``rho`` the measurement's rate ρ (NED, m/s²; NULL: held): y(τ) = y + ρ τ over the
        step, observer.zoh_earth's ramp terms."""
        cdef double* E = self.E
        cdef double we[3]
        cdef double a[3]
        cdef double z[3]
        cdef double* t
        cdef double e, hp1, h2p2, g, wl, wm1, wm2, ym1, ym2, zl0, cl
        cdef double w0, w1, w2, y0, y1, y2
        cdef double r0 = 0.0, r1 = 0.0, r2 = 0.0
        cdef double c0, c1_, c2, rm1, rm2
        cdef double q0, q1, q2
        cdef bint ramp = rho != NULL
        cdef int i, l_, m1, m2
        if ramp:
            r0, r1, r2 = rho[0], rho[1], rho[2]
        rotate_c(E, w, we)  # ω_e = E ω
        # a = E Γ = E f + (0, 0, g): gravity in body axes (9) is Eᵀ (0, 0, g)
        rotate_c(E, f, a)
        a[2] += self.g_mps2
        t = self._terms(h)
        for i in range(4):
            e = t[3 * i]
            hp1 = t[3 * i + 1]
            h2p2 = t[3 * i + 2]
            g = self.gam[i]
            rotate_c(E, &self.x[i][0], z)  # z = E x̂
            l_ = lost[i]
            if l_ < 0:  # C = I: ż = a − ω_e × y + γ (y − z)
                y0, y1, y2 = y[0], y[1], y[2]
                w0, w1, w2 = we[0], we[1], we[2]
                z[0] = e * z[0] + hp1 * (a[0] - (w1 * y2 - w2 * y1) + g * y0)
                z[1] = e * z[1] + hp1 * (a[1] - (w2 * y0 - w0 * y2) + g * y1)
                z[2] = e * z[2] + hp1 * (a[2] - (w0 * y1 - w1 * y0) + g * y2)
                q0, q1, q2 = r0, r1, r2
                if self.rotate_y:
                    # the step's frame turns by ω_e τ from E's: the measurement seen from
                    # it is exp(−[ω_e]× τ) y ≈ y − (ω_e × y) τ (observer.frame_ramp_mps2)
                    q0 = q0 - (w1 * y2 - w2 * y1)
                    q1 = q1 - (w2 * y0 - w0 * y2)
                    q2 = q2 - (w0 * y1 - w1 * y0)
                if ramp or self.rotate_y:  # + h² φ2 (γ ρ − ω_e × ρ)
                    c0 = g * q0 - (w1 * q2 - w2 * q1)
                    c1_ = g * q1 - (w2 * q0 - w0 * q2)
                    c2 = g * q2 - (w0 * q1 - w1 * q0)
                    z[0] = z[0] + h2p2 * c0
                    z[1] = z[1] + h2p2 * c1_
                    z[2] = z[2] + h2p2 * c2
            else:  # lost axis l, measured m1 = l+1, m2 = l+2 (cyclic); ż_l = (a − ω_e × Ȳ)_l
                m1 = (l_ + 1) % 3
                m2 = (l_ + 2) % 3
                wl = we[l_]
                wm1 = we[m1]
                wm2 = we[m2]
                ym1 = y[m1]
                ym2 = y[m2]
                zl0 = z[l_]
                cl = a[l_] - (wm1 * ym2 - wm2 * ym1)
                z[l_] = zl0 + h * cl
                z[m1] = e * z[m1] + hp1 * (a[m1] + wl * ym2 + g * ym1 - wm2 * zl0) - h2p2 * wm2 * cl
                z[m2] = e * z[m2] + hp1 * (a[m2] - wl * ym1 + g * ym2 + wm1 * zl0) + h2p2 * wm1 * cl
                if ramp:  # ρ on the measured axes only (ρ_l = 0): observer.zoh_earth
                    rm1 = r0 if m1 == 0 else (r1 if m1 == 1 else r2)
                    rm2 = r0 if m2 == 0 else (r1 if m2 == 1 else r2)
                    z[l_] = z[l_] + (-(wm1 * rm2 - wm2 * rm1)) * (0.5 * h * h)
                    z[m1] = z[m1] + h2p2 * (g * rm1 + wl * rm2)
                    z[m2] = z[m2] + h2p2 * (g * rm2 - wl * rm1)
            rotate_t_c(E, z, &self.x[i][0])  # x̂ = Eᵀ z
