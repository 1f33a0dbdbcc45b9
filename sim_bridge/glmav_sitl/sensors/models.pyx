"""Sensor models: IMU, attitude, position/velocity, with noise, bias and scheduled faults.

Every random draw comes from a seeded :class:`numpy.random.Generator` handed in by
the caller (one per sensor, spawned from one :class:`numpy.random.SeedSequence`).
Each sensor reads its generator's standard normals through :class:`Normals`, which
draws them in blocks: a generator's normals come out in the same sequence whether drawn
6 at a time or 512 (numpy fills an array one normal after the other), so the samples
are those of drawing per sample, for a fraction of the cost.

Compiled (Cython): the ideal profile samples ~750 IMU, 100 attitude and 30 position
messages a simulated second, the autopilot profile its IMU at 1 kHz. Every operation is
the former Python code's in its order (setup.py: no fused multiply-add), so seeded
samples did not change.

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

from libc.math cimport M_PI, atan2, copysign, cos, fmod, sin, sqrt

import numpy as np

from glmav_sitl.dynamics.frames import rotate_ned_to_body

_AXIS = {"n": 0, "e": 1, "d": 2}
#: normals drawn at once by :class:`Normals`
cdef enum:
    BLOCK = 512


cdef class Normals:
    """A generator's standard normals, drawn ``BLOCK`` at a time (module docstring)."""

    cdef object rng
    cdef double[::1] blk
    cdef Py_ssize_t i

    def __init__(self, rng):
        self.rng = rng
        self.blk = np.empty(0)
        self.i = 0

    cdef inline double next(self) except? -1e300:
        if self.i >= self.blk.shape[0]:
            self.blk = self.rng.standard_normal(BLOCK)
            self.i = 0
        self.i += 1
        return self.blk[self.i - 1]

    def draw(self):
        """The next normal."""
        return self.next()


cdef class ImuModel:
    """Gyro and accelerometer with turn-on bias, bias random walk and white noise."""

    cdef Normals _n
    cdef double _noise, _gd, _ad, _grw, _arw, _t_last_s
    cdef double gb[3]
    cdef double ab[3]
    cdef tuple _accel_faults

    def __init__(self, cfg, rng, faults=()):
        c = cfg.imu
        self._n = Normals(rng)
        self._noise = cfg.noise_scale if cfg.noise else 0.0
        cdef double bscale = cfg.bias_scale if cfg.bias else 0.0
        self._gd = c.gyro_noise_density * self._noise
        self._ad = c.accel_noise_density * self._noise
        self._grw = c.gyro_bias_random_walk * bscale
        self._arw = c.accel_bias_random_walk * bscale
        cdef double gs = c.gyro_bias_sigma, as_ = c.accel_bias_sigma
        cdef int i
        for i in range(3):
            self.gb[i] = self._n.next() * gs * bscale
        for i in range(3):
            self.ab[i] = self._n.next() * as_ * bscale
        self._accel_faults = tuple(f for f in faults if f.sensor == "accel")
        self._t_last_s = 0.0

    @property
    def gyro_bias_radps(self):
        """The gyro bias now (rad/s, FRD), a new list."""
        return [self.gb[0], self.gb[1], self.gb[2]]

    @property
    def accel_bias_mps2(self):
        """The accelerometer bias now (m/s^2, FRD), a new list."""
        return [self.ab[0], self.ab[1], self.ab[2]]

    def accel_fault_bias(self, double t_s):
        cdef double bx = 0.0, by = 0.0, bz = 0.0
        for f in self._accel_faults:
            if f.t_start_s <= t_s < f.t_end_s:
                bx += f.vector[0]
                by += f.vector[1]
                bz += f.vector[2]
        return (bx, by, bz)

    cdef inline void _fault_bias(self, double t_s, double* fb):
        if self._accel_faults:
            fb[0], fb[1], fb[2] = self.accel_fault_bias(t_s)
        else:
            fb[0] = fb[1] = fb[2] = 0.0

    def sample(self, double t_s, omega_body_radps, f_body_mps2, double rate_hz):
        """(gyro rad/s, accel m/s^2) in FRD at ``t_s`` for a stream sampled at ``rate_hz``."""
        cdef double dt = t_s - self._t_last_s
        cdef double s, sr, sg, sa
        cdef double ng[3]
        cdef double na[3]
        cdef double fb[3]
        cdef double n6[6]
        cdef int i
        if dt > 0.0 and (self._grw > 0.0 or self._arw > 0.0):
            for i in range(6):
                n6[i] = self._n.next()
            s = sqrt(dt)
            for i in range(3):
                self.gb[i] += self._grw * s * n6[i]
                self.ab[i] += self._arw * s * n6[3 + i]
        if t_s > self._t_last_s:
            self._t_last_s = t_s
        sr = sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        sg = self._gd * sr
        sa = self._ad * sr
        if sg > 0.0 or sa > 0.0:
            for i in range(6):
                n6[i] = self._n.next()
            for i in range(3):
                ng[i] = sg * n6[i]
                na[i] = sa * n6[3 + i]
        else:
            for i in range(3):
                ng[i] = 0.0
                na[i] = 0.0
        self._fault_bias(t_s, fb)
        cdef double w0 = omega_body_radps[0], w1 = omega_body_radps[1], w2 = omega_body_radps[2]
        cdef double f0 = f_body_mps2[0], f1 = f_body_mps2[1], f2 = f_body_mps2[2]
        return (
            (w0 + self.gb[0] + ng[0], w1 + self.gb[1] + ng[1], w2 + self.gb[2] + ng[2]),
            (
                f0 + self.ab[0] + na[0] + fb[0],
                f1 + self.ab[1] + na[1] + fb[1],
                f2 + self.ab[2] + na[2] + fb[2],
            ),
        )

    def sample_fast(self, double t_s, omega_body_radps, f_body_mps2, double rate_hz):
        """:meth:`sample` for callers at kHz rates (the autopilot profile's fast IMU): the
        same model and statistics, 12 normals a sample in a fixed layout (white noise
        first, then the bias walk), so the draw order, and the numbers, differ from
        :meth:`sample`'s."""
        cdef double n[12]
        cdef int i
        for i in range(12):
            n[i] = self._n.next()
        cdef double dt = t_s - self._t_last_s
        cdef double s, g, a, sr, sg, sa
        cdef double fb[3]
        if dt > 0.0 and (self._grw > 0.0 or self._arw > 0.0):
            s = sqrt(dt)
            g = self._grw * s
            a = self._arw * s
            self.gb[0] += g * n[6]
            self.gb[1] += g * n[7]
            self.gb[2] += g * n[8]
            self.ab[0] += a * n[9]
            self.ab[1] += a * n[10]
            self.ab[2] += a * n[11]
        if t_s > self._t_last_s:
            self._t_last_s = t_s
        sr = sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        sg = self._gd * sr
        sa = self._ad * sr
        self._fault_bias(t_s, fb)
        cdef double w0 = omega_body_radps[0], w1 = omega_body_radps[1], w2 = omega_body_radps[2]
        cdef double f0 = f_body_mps2[0], f1 = f_body_mps2[1], f2 = f_body_mps2[2]
        return (
            (w0 + self.gb[0] + sg * n[0], w1 + self.gb[1] + sg * n[1], w2 + self.gb[2] + sg * n[2]),
            (
                f0 + self.ab[0] + sa * n[3] + fb[0],
                f1 + self.ab[1] + sa * n[4] + fb[1],
                f2 + self.ab[2] + sa * n[5] + fb[2],
            ),
        )


cdef class AttitudeSensor:
    """ATTITUDE: Euler angles (rad) and body rates (rad/s) with white noise."""

    cdef double _sa, _gd
    cdef Normals _n

    def __init__(self, cfg, rng):
        cdef double k = cfg.noise_scale if cfg.noise else 0.0
        self._sa = cfg.attitude_sigma_rad * k
        self._gd = cfg.imu.gyro_noise_density * k
        self._n = Normals(rng)

    def sample(self, euler_rad, omega_body_radps, double rate_hz):
        if self._sa <= 0.0 and self._gd <= 0.0:
            return euler_rad, omega_body_radps
        cdef double n[6]
        cdef int i
        for i in range(6):
            n[i] = self._n.next()
        cdef double sa = self._sa
        cdef double sg = self._gd * sqrt(rate_hz) if rate_hz > 0.0 else 0.0
        cdef double phi = <double>euler_rad[0] + sa * n[0]
        cdef double theta = <double>euler_rad[1] + sa * n[1]
        cdef double psi = <double>euler_rad[2] + sa * n[2]
        psi = atan2(sin(psi), cos(psi))  # keep (-pi, pi]
        return (phi, theta, psi), (
            <double>omega_body_radps[0] + sg * n[3],
            <double>omega_body_radps[1] + sg * n[4],
            <double>omega_body_radps[2] + sg * n[5],
        )


cdef class PositionVelocitySensor:
    """LOCAL_POSITION_NED with GNSS-like white noise and per-axis velocity faults."""

    cdef double _sp, _sv
    cdef Normals _n
    cdef object _frng
    cdef tuple _faults
    cdef dict _frozen
    cdef list _last_v

    def __init__(self, cfg, rng, fault_rng, faults=()):
        cdef double k = cfg.noise_scale if cfg.noise else 0.0
        self._sp = cfg.position_sigma_m * k
        self._sv = cfg.velocity_sigma_mps * k
        self._n = Normals(rng)
        self._frng = fault_rng
        self._faults = tuple(f for f in faults if f.sensor == "velocity")
        self._frozen = {}
        self._last_v = [0.0, 0.0, 0.0]

    @property
    def velocity_sigma_mps(self):
        return self._sv

    def set_velocity_sigma_mps(self, double sigma_mps):
        """Change the velocity noise at run time (a ground station's parameter)."""
        self._sv = sigma_mps

    def set_faults(self, faults):
        """Replace the velocity faults (a ground station's fault injection)."""
        self._faults = tuple(f for f in faults if f.sensor == "velocity")
        self._frozen.clear()

    def sample(self, double t_s, p_ned_m, v_ned_mps):
        cdef double n[6]
        cdef int i
        cdef double sp, sv
        if self._sp > 0.0 or self._sv > 0.0:
            for i in range(6):
                n[i] = self._n.next()
            sp = self._sp
            sv = self._sv
            pos = (
                <double>p_ned_m[0] + sp * n[0],
                <double>p_ned_m[1] + sp * n[1],
                <double>p_ned_m[2] + sp * n[2],
            )
            vel = [
                <double>v_ned_mps[0] + sv * n[3],
                <double>v_ned_mps[1] + sv * n[4],
                <double>v_ned_mps[2] + sv * n[5],
            ]
        else:
            pos = p_ned_m
            vel = list(v_ned_mps)
        if self._faults:
            for i, f in enumerate(self._faults):
                ax = _AXIS[f.axis]
                if not f.t_start_s <= t_s < f.t_end_s:
                    self._frozen.pop(i, None)
                    continue
                if f.kind == "dropout":
                    vel[ax] = float("nan")
                elif f.kind == "freeze":
                    vel[ax] = self._frozen.setdefault(i, self._last_v[ax])
                elif f.kind == "bias":
                    vel[ax] += f.magnitude
                elif f.kind == "noise":
                    vel[ax] += f.magnitude * float(self._frng.standard_normal())
        self._last_v = list(vel)
        return pos, (vel[0], vel[1], vel[2])


cdef enum:
    MAX_HARMONICS = 16


cdef inline double _py_mod(double x, double y) noexcept nogil:
    """``x % y`` as Python computes it for floats (the result has the sign of ``y``)."""
    cdef double m = fmod(x, y)
    if m != 0.0:
        if (y < 0.0) != (m < 0.0):
            m += y
    else:
        m = copysign(0.0, y)
    return m


cdef class FastImu:
    """The ``autopilot`` profile's fast IMU (:mod:`glmav_sitl.sensors.autopilot`): each
    sample, the mean specific force over the IMU period ``R^T ((v_k - v_{k-1}) / T - g
    e_d)`` and the true rate through :meth:`ImuModel.sample_fast`, plus the rotors'
    vibration lines; the sums of the samples since the attitude estimator last took
    them. The operations of the former Python code, in its order.

    ``vib``: per rotor, ``(harmonic, 6 coefficients of sin(h phi), 6 of cos(h phi))``
    over (accel x, y, z, gyro x, y, z)."""

    cdef ImuModel imu
    cdef double g, ti, rate_hz
    cdef double v_prev[3]
    cdef double phase[2]
    cdef double trim2[2]
    cdef bint vib_on
    cdef int n_terms[2]
    cdef double harm[2][MAX_HARMONICS]
    cdef double cs[2][MAX_HARMONICS][6]
    cdef double cc[2][MAX_HARMONICS][6]
    cdef double sums[6]
    cdef int n_sum
    cdef public tuple gyro_radps
    cdef public tuple accel_mps2

    def __init__(
        self, ImuModel imu, double g_mps2, int interval_us, v0_ned_mps, trim2, vib,
        bint vib_on, accel0_mps2,
    ):
        cdef int r, k, i
        self.imu = imu
        self.g = g_mps2
        self.ti = interval_us / 1e6
        self.rate_hz = 1e6 / interval_us
        for i in range(3):
            self.v_prev[i] = v0_ned_mps[i]
        for r in range(2):
            self.phase[r] = 0.0
            self.trim2[r] = trim2[r]
            if len(vib[r]) > MAX_HARMONICS:
                raise ValueError(f"at most {MAX_HARMONICS} vibration harmonics")
            self.n_terms[r] = len(vib[r])
            for k, (h, c_sin, c_cos) in enumerate(vib[r]):
                self.harm[r][k] = h
                for i in range(6):
                    self.cs[r][k][i] = c_sin[i]
                    self.cc[r][k][i] = c_cos[i]
        self.vib_on = vib_on
        for i in range(6):
            self.sums[i] = 0.0
        self.n_sum = 0
        self.gyro_radps = (0.0, 0.0, 0.0)
        self.accel_mps2 = tuple(accel0_mps2)

    def sample(self, long long t_us, double qw, double qx, double qy, double qz, v_ned, omega,
               double w1, double w2):
        """One fast sample at ``t_us`` of the state (attitude, NED velocity, body rates,
        rotor speeds); kept in ``gyro_radps``, ``accel_mps2`` and the sums."""
        cdef double ti = self.ti
        cdef double v0 = v_ned[0], v1 = v_ned[1], v2 = v_ned[2]
        cdef double fx = (v0 - self.v_prev[0]) / ti
        cdef double fy = (v1 - self.v_prev[1]) / ti
        cdef double fz = (v2 - self.v_prev[2]) / ti - self.g
        self.v_prev[0] = v0
        self.v_prev[1] = v1
        self.v_prev[2] = v2
        # R(q)^T f: the simulator's one rotation (dynamics.frames; a Python call per fast
        # sample, ~0.3 µs: not worth a second copy of it here)
        f_body = rotate_ned_to_body((qw, qx, qy, qz), (fx, fy, fz))
        gyro, acc = self.imu.sample_fast(t_us / 1e6, omega, f_body, self.rate_hz)
        cdef double ax = acc[0], ay = acc[1], az = acc[2]
        cdef double gx = gyro[0], gy = gyro[1], gz = gyro[2]
        cdef double w_r, ph, s2, sn, cn
        cdef double two_pi = 2.0 * M_PI
        cdef double* a
        cdef double* b
        cdef int r, k
        if self.vib_on:
            for r in range(2):
                w_r = w1 if r == 0 else w2
                ph = _py_mod(self.phase[r] + w_r * ti, two_pi)
                self.phase[r] = ph
                s2 = w_r * w_r * self.trim2[r]
                for k in range(self.n_terms[r]):
                    sn = sin(self.harm[r][k] * ph) * s2
                    cn = cos(self.harm[r][k] * ph) * s2
                    a = self.cs[r][k]
                    b = self.cc[r][k]
                    ax += a[0] * sn + b[0] * cn
                    ay += a[1] * sn + b[1] * cn
                    az += a[2] * sn + b[2] * cn
                    gx += a[3] * sn + b[3] * cn
                    gy += a[4] * sn + b[4] * cn
                    gz += a[5] * sn + b[5] * cn
        self.accel_mps2 = (ax, ay, az)
        self.gyro_radps = (gx, gy, gz)
        self.sums[0] += ax
        self.sums[1] += ay
        self.sums[2] += az
        self.sums[3] += gx
        self.sums[4] += gy
        self.sums[5] += gz
        self.n_sum += 1

    def take_sums(self):
        """``(sums of (ax, ay, az, gx, gy, gz), n)`` since the last call; reset them."""
        out = ([self.sums[i] for i in range(6)], self.n_sum)
        for i in range(6):
            self.sums[i] = 0.0
        self.n_sum = 0
        return out
