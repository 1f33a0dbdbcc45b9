"""Cascaded flight controller of the simulated GLMAV (flies on the true state).

position -> velocity -> thrust vector / attitude -> body rates -> actuators:

1. Velocity command from the setpoint: ``v_cmd = k_pos (p_sp - p)`` (limited), or a
   velocity / turning-climb setpoint.
2. Acceleration command ``a_cmd = k_v (v_cmd - v) + k_i int(v_cmd - v) + a_ff``; the
   thrust vector cancels the modelled body aerodynamics (eqs (6)-(8), no wind):
   ``T = m a_cmd - m g e3 - F_aero`` (NED), tilt limited.
3. Attitude from the thrust direction (body -z along T) and the yaw setpoint; the
   quaternion error gives rate commands; rate errors give angular accelerations and
   moments ``tau = I alpha + omega x I omega``.
4. Actuators: collective and yaw solve the 2x2 system of eqs (5) and (10)
   ``sigma alpha W1^2 + sigma beta c W2^2 = T_axial``, ``gamma1 W1^2 + gamma2 W2^2 = N``;
   the cyclic inverts eq. (10): ``sin dcx = -L / (d beta W2^2)``,
   ``sin dcy = M / (d beta W2^2 cos dcx)``, clipped to the swash-plate limit.

The controller sees the truth: scenarios then fly the same whatever sensor faults
are injected (faults only change what the vehicle reports).

Compiled (Cython): the law runs at the control rate inside every simulated second
(250 Hz), ~40 us a call in Python. Every operation is the former Python code's, in its
order (setup.py: no fused multiply-add; sin, cos, asin, atan2, tan, sqrt are the libm
calls Python's math makes; ``hypot`` is Python's own, whose rounding libm's need not
share), so seeded flights did not change.
"""

from libc.math cimport asin, atan2, cos, fabs, sin, sqrt, tan
from math import hypot as _py_hypot


cdef inline double _clip(double x, double lo, double hi) noexcept nogil:
    return lo if x < lo else (hi if x > hi else x)


cdef inline double hypot(double a, double b):
    return _py_hypot(a, b)  # Python's (module docstring)


cdef class Controller:
    """``update(t_s, x) -> u`` at the control rate; ``u`` as in :mod:`glmav_sitl.dynamics.model`."""

    cdef public object p
    cdef public list setpoints
    cdef public double dt
    cdef public tuple last_attitude_sp_rad
    cdef object _k
    # gains (copied from k when it is set)
    cdef double pos_p, vel_p, vel_i, att_p, rate_p, yaw_p, yaw_rate_p
    cdef double max_tilt, max_speed, max_accel, max_rate
    # vehicle constants
    cdef double m, g, sigma, alpha, beta, d, gamma1, gamma2, ixx, iyy, izz, swash_limit
    cdef double _kx, _ky, _kz, _dw
    cdef Py_ssize_t _idx
    # the active setpoint: its Setpoint, start time, start position and yaw
    cdef object _sp
    cdef double _t0, _yaw0
    cdef double _p0[3]
    cdef double _vi[3]

    def __init__(self, p, gains, setpoints, double control_dt_s):
        self.p = p
        self.k = gains
        self.setpoints = sorted(setpoints, key=lambda s: s.t_s)
        self.dt = control_dt_s
        self._idx = -1
        self._sp = None
        self._vi[:] = [0.0, 0.0, 0.0]
        self.m, self.g, self.sigma, self.alpha, self.beta = p.m, p.g, p.sigma, p.alpha, p.beta
        self.d, self.gamma1, self.gamma2 = p.d, p.gamma1, p.gamma2
        self.ixx, self.iyy, self.izz, self.swash_limit = p.ixx, p.iyy, p.izz, p.swash_limit
        self._kx = 0.5 * p.rho * p.side_area_m2 * p.cx
        self._ky = 0.5 * p.rho * p.side_area_m2 * p.cy
        self._kz = 0.5 * p.rho * p.top_area_m2 * p.cz
        self._dw = p.downwash_hover / sqrt(p.m * p.g)
        self.last_attitude_sp_rad = (0.0, 0.0, 0.0)

    @property
    def k(self):
        """The gains (a :class:`~glmav_sitl.scenario.ControllerGains`); settable."""
        return self._k

    @k.setter
    def k(self, gains):
        self._k = gains
        self.pos_p, self.vel_p, self.vel_i = gains.pos_p, gains.vel_p, gains.vel_i
        self.att_p, self.rate_p = gains.att_p, gains.rate_p
        self.yaw_p, self.yaw_rate_p = gains.yaw_p, gains.yaw_rate_p
        self.max_tilt, self.max_speed = gains.max_tilt_rad, gains.max_speed_mps
        self.max_accel, self.max_rate = gains.max_accel_mps2, gains.max_rate_radps

    cdef void _activate(self, object sp, double t_s, double pn, double pe, double pd, double yaw):
        self._sp = sp
        self._t0 = t_s
        self._p0[0] = pn
        self._p0[1] = pe
        self._p0[2] = pd
        self._yaw0 = yaw

    def command(self, sp, double t_s, x):
        """Fly ``sp`` from now on, in place of the scheduled setpoints (a ground station's
        command). ``hold`` and ``position`` without a position hold where ``x`` is now."""
        self._idx = len(self.setpoints)  # the schedule is over: no scheduled setpoint replaces it
        cdef double qw = x[6], qx = x[7], qy = x[8], qz = x[9]
        cdef double yaw = atan2(2 * (qx * qy + qw * qz), 1 - 2 * (qy * qy + qz * qz))
        self._activate(sp, t_s, x[0], x[1], x[2], yaw)
        if sp.kind == "idle":
            self._vi[:] = [0.0, 0.0, 0.0]

    def update(self, double t_s, x):
        cdef double qw = x[6], qx = x[7], qy = x[8], qz = x[9]
        cdef double px = x[0], py = x[1], pz = x[2]
        cdef double vu = x[3], vv = x[4], vw = x[5]
        cdef double wp = x[10], wq = x[11], wr_ = x[12]
        cdef double w1 = x[13], w2 = x[14], dcx = x[15], dcy = x[16]
        # R(q), as frames.rotation_from_quat
        cdef double r11 = 1 - 2 * (qy * qy + qz * qz)
        cdef double r12 = 2 * (qx * qy - qw * qz)
        cdef double r13 = 2 * (qx * qz + qw * qy)
        cdef double r21 = 2 * (qx * qy + qw * qz)
        cdef double r22 = 1 - 2 * (qx * qx + qz * qz)
        cdef double r23 = 2 * (qy * qz - qw * qx)
        cdef double r31 = 2 * (qx * qz - qw * qy)
        cdef double r32 = 2 * (qy * qz + qw * qx)
        cdef double r33 = 1 - 2 * (qx * qx + qy * qy)
        cdef double yaw = atan2(r21, r11)
        cdef double vn = r11 * vu + r12 * vv + r13 * vw
        cdef double ve = r21 * vu + r22 * vv + r23 * vw
        cdef double vd = r31 * vu + r32 * vv + r33 * vw
        cdef double v_cmd[3]
        cdef double a_ff[3]
        cdef double a_cmd[3]
        cdef double v_ned[3]
        cdef double e, vh, ah, psi, yaw_sp, lo, hi, speed, rate
        cdef int i
        cdef Py_ssize_t j = self._idx
        cdef Py_ssize_t n_sp = len(self.setpoints)
        # the scheduled setpoint now
        while j + 1 < n_sp and self.setpoints[j + 1].t_s <= t_s:
            j += 1
        if j != self._idx:
            self._idx = j
            self._activate(self.setpoints[j], t_s, px, py, pz, yaw)
        sp = self._sp
        if sp is None or sp.kind == "idle":
            self._vi[:] = [0.0, 0.0, 0.0]
            return [0.0, 0.0, 0.0, 0.0]
        kind = sp.kind
        v_ned[0] = vn
        v_ned[1] = ve
        v_ned[2] = vd
        a_ff[0] = a_ff[1] = a_ff[2] = 0.0
        yaw_sp = sp.yaw_rad if sp.yaw_rad is not None else self._yaw0
        if kind == "position" or kind == "hold":
            if sp.position_ned_m is not None:
                target = sp.position_ned_m
                v_cmd[0] = self.pos_p * (<double>target[0] - px)
                v_cmd[1] = self.pos_p * (<double>target[1] - py)
                v_cmd[2] = self.pos_p * (<double>target[2] - pz)
            else:
                v_cmd[0] = self.pos_p * (self._p0[0] - px)
                v_cmd[1] = self.pos_p * (self._p0[1] - py)
                v_cmd[2] = self.pos_p * (self._p0[2] - pz)
        elif kind == "velocity":
            vel = sp.velocity_ned_mps
            v_cmd[0] = vel[0]
            v_cmd[1] = vel[1]
            v_cmd[2] = vel[2]
        else:  # turn: heading sweeps at turn_rate, speed along heading, climb rate up
            speed = sp.speed_mps
            rate = sp.turn_rate_radps
            psi = self._yaw0 + rate * (t_s - self._t0)
            yaw_sp = psi
            v_cmd[0] = speed * cos(psi)
            v_cmd[1] = speed * sin(psi)
            v_cmd[2] = -<double>sp.climb_rate_mps
            # centripetal feed-forward: d/dt of the commanded velocity
            a_ff[0] = -speed * rate * sin(psi)
            a_ff[1] = speed * rate * cos(psi)
        vh = hypot(v_cmd[0], v_cmd[1])
        if vh > self.max_speed:
            v_cmd[0] *= self.max_speed / vh
            v_cmd[1] *= self.max_speed / vh
        v_cmd[2] = _clip(v_cmd[2], -self.max_speed, self.max_speed)
        # velocity loop (PI) -> acceleration command, NED
        lo = -self.max_accel / self.vel_i
        hi = self.max_accel / self.vel_i
        for i in range(3):
            e = v_cmd[i] - v_ned[i]
            # conditional integration (anti-windup): only near the commanded velocity
            if fabs(e) < 1.0:
                self._vi[i] = _clip(self._vi[i] + e * self.dt, lo, hi)
            a_cmd[i] = self.vel_p * e + self.vel_i * self._vi[i] + a_ff[i]
        ah = hypot(a_cmd[0], a_cmd[1])
        if ah > self.max_accel:
            a_cmd[0] *= self.max_accel / ah
            a_cmd[1] *= self.max_accel / ah
        a_cmd[2] = _clip(a_cmd[2], -self.max_accel, self.max_accel)
        # modelled body aerodynamics, eqs (6)-(8) with no wind, body -> NED
        cdef double m = self.m, g = self.g
        cdef double t_ax = self.sigma * (
            self.alpha * w1 * w1 + self.beta * w2 * w2 * cos(dcx) * cos(dcy)
        )
        cdef double vp = self._dw * sqrt(t_ax) if t_ax > 0.0 else 0.0
        cdef double ax_ = -vu, ay_ = -vv, az_ = vp - vw
        cdef double nrm = sqrt(ax_ * ax_ + ay_ * ay_ + az_ * az_)
        cdef double fb0 = self._kx * ax_ * nrm, fb1 = self._ky * ay_ * nrm, fb2 = self._kz * az_ * nrm
        cdef double fa0 = r11 * fb0 + r12 * fb1 + r13 * fb2
        cdef double fa1 = r21 * fb0 + r22 * fb1 + r23 * fb2
        cdef double fa2 = r31 * fb0 + r32 * fb1 + r33 * fb2
        # thrust vector (NED): T = m a - m g e3 - F_aero
        cdef double tn = m * a_cmd[0] - fa0
        cdef double te = m * a_cmd[1] - fa1
        cdef double td = m * (a_cmd[2] - g) - fa2
        cdef double tcap = -0.2 * m * g
        td = tcap if tcap < td else td  # always some upward thrust (min(td, tcap))
        cdef double th = hypot(tn, te)
        cdef double tmax = -td * tan(self.max_tilt)
        if th > tmax:
            tn *= tmax / th
            te *= tmax / th
        cdef double tnorm = sqrt(tn * tn + te * te + td * td)
        cdef double cpsi = cos(yaw_sp), spsi = sin(yaw_sp)
        cdef double tf = cpsi * tn + spsi * te
        cdef double tr = -spsi * tn + cpsi * te
        cdef double phi_sp = asin(_clip(tr / tnorm, -1.0, 1.0))
        cdef double theta_sp = atan2(-tf, -td)
        self.last_attitude_sp_rad = (phi_sp, theta_sp, yaw_sp)
        # qe = conj(q) * q_sp (frames.quat_from_euler, quat_conj, quat_mul)
        cdef double cr = cos(phi_sp / 2), sr = sin(phi_sp / 2)
        cdef double cp = cos(theta_sp / 2), sp_ = sin(theta_sp / 2)
        cdef double cy = cos(yaw_sp / 2), sy = sin(yaw_sp / 2)
        cdef double bw = cr * cp * cy + sr * sp_ * sy
        cdef double bx = sr * cp * cy - cr * sp_ * sy
        cdef double by = cr * sp_ * cy + sr * cp * sy
        cdef double bz = cr * cp * sy - sr * sp_ * cy
        cdef double aw = qw, ax = -qx, ay = -qy, az = -qz
        cdef double qe0 = aw * bw - ax * bx - ay * by - az * bz
        cdef double qe1 = aw * bx + ax * bw + ay * bz - az * by
        cdef double qe2 = aw * by - ax * bz + ay * bw + az * bx
        cdef double qe3 = aw * bz + ax * by - ay * bx + az * bw
        if qe0 < 0.0:
            qe0, qe1, qe2, qe3 = -qe0, -qe1, -qe2, -qe3
        cdef double wr = self.max_rate
        cdef double wc0 = _clip(2.0 * self.att_p * qe1, -wr, wr)
        cdef double wc1 = _clip(2.0 * self.att_p * qe2, -wr, wr)
        cdef double wc2 = _clip(2.0 * self.yaw_p * qe3, -wr, wr)
        cdef double al0 = self.rate_p * (wc0 - wp)
        cdef double al1 = self.rate_p * (wc1 - wq)
        cdef double al2 = self.yaw_rate_p * (wc2 - wr_)
        # eq. (4): tau = I alpha + omega x I omega
        cdef double ixx = self.ixx, iyy = self.iyy, izz = self.izz
        cdef double L = ixx * al0 + (wq * izz * wr_ - wr_ * iyy * wq)
        cdef double M = iyy * al1 + (wr_ * ixx * wp - wp * izz * wr_)
        cdef double N = izz * al2 + (wp * iyy * wq - wq * ixx * wp)
        # collective along the actual -z_b (max(0.0, .))
        cdef double t_axial = -(tn * r13 + te * r23 + td * r33)
        t_axial = t_axial if t_axial > 0.0 else 0.0
        # eqs (5), (10): solve for W1^2, W2^2
        cdef double c = cos(dcx) * cos(dcy)
        cdef double sa = self.sigma * self.alpha, sbc = self.sigma * self.beta * c
        cdef double det = sa * self.gamma2 - sbc * self.gamma1
        cdef double w1s = (t_axial * self.gamma2 - sbc * N) / det
        cdef double w2s = (sa * N - self.gamma1 * t_axial) / det
        cdef double w1c = sqrt(0.0 if 0.0 > w1s else w1s)  # max(w1s, 0.0)
        cdef double w2c = sqrt(0.0 if 0.0 > w2s else w2s)
        # cyclic: invert eq. (10) with the actual lower rotor speed (max(., 0.05 m g))
        cdef double b2 = self.beta * w2 * w2
        cdef double b2min = 0.05 * m * g
        b2 = b2min if b2min > b2 else b2
        cdef double smax = sin(self.swash_limit)
        cdef double sx = _clip(-L / (self.d * b2), -smax, smax)
        cdef double dcx_c = asin(sx)
        cdef double sy_ = _clip(M / (self.d * b2 * cos(dcx_c)), -smax, smax)
        return [w1c, w2c, dcx_c, asin(sy_)]
