"""One-sample IMU shock rejection (pure; compiled: it runs at every IMU sample).

A gun-launched vehicle's IMU sees shocks, and a CRC-valid frame can carry one corrupt
value within the plausible range (:data:`glmav_observer.ingest.convert.IMU_MAX_F_MPS2`).
Integrated over a 20 ms hold, one 1000 m/s² sample is a 20 m/s velocity step. A sample
whose specific force differs from the last accepted one by more than the spike threshold
is held out; if the next sample agrees with it (the level really changed, e.g. at launch)
that next sample is accepted, so a real step costs one sample of delay.

Threshold: max(``floor_mps2``, ``k_sigma`` × the running RMS of ‖Δf‖ between accepted
samples), so a vibrating IMU (ArduPilot SITL with SIM_ACC1_RND = 5: ‖Δf‖ RMS ≈ 12 m/s²)
raises its own bar.

‖Δf‖ is √(Δx² + Δy² + Δz²) in C; the former Python code's ``math.dist`` rounds its
scaled sum differently, by an ulp at most (the golden replays are unchanged by it).
"""

from libc.math cimport sqrt


cdef inline double _dist(double a0, double a1, double a2, double b0, double b1, double b2) noexcept:
    cdef double d0 = a0 - b0, d1 = a1 - b1, d2 = a2 - b2
    return sqrt(d0 * d0 + d1 * d1 + d2 * d2)


cdef class Despiker:
    """Holds out isolated specific-force spikes (module docstring)."""

    cdef public double floor_mps2
    cdef public double k_sigma
    cdef double _k
    cdef object _last  # the last accepted sample (a tuple), None before the first
    cdef double l0, l1, l2
    cdef bint has_candidate
    cdef double c0, c1, c2
    cdef double _ms_diff

    def __init__(self, double floor_mps2=40.0, double k_sigma=8.0, int tau_samples=100):
        self.floor_mps2 = floor_mps2
        self.k_sigma = k_sigma
        self._k = 1.0 / tau_samples
        self._last = None
        self.has_candidate = False
        self._ms_diff = 0.0

    def noise_var_mps2(self):
        """σ_f² per axis: E‖Δf‖² = 2 · 3 σ_f² for white noise on three axes."""
        return self._ms_diff / 6.0

    cdef inline double _threshold(self) noexcept:
        cdef double t = self.k_sigma * sqrt(self._ms_diff)
        return t if t > self.floor_mps2 else self.floor_mps2

    def threshold_mps2(self):
        return self._threshold()

    def filter(self, f_body_mps2):
        """The sample to use, or None when ``f_body_mps2`` is held out as a spike."""
        cdef double f0, f1, f2, d, thr
        f0, f1, f2 = f_body_mps2
        if self._last is None:
            self._last = f_body_mps2
            self.l0, self.l1, self.l2 = f0, f1, f2
            return f_body_mps2
        d = _dist(f0, f1, f2, self.l0, self.l1, self.l2)
        thr = self._threshold()
        cdef bint had = self.has_candidate
        self.has_candidate = False
        if d > thr and (not had or _dist(f0, f1, f2, self.c0, self.c1, self.c2) > thr):
            self.has_candidate = True
            self.c0, self.c1, self.c2 = f0, f1, f2
            return None
        if d <= thr:  # a step confirmed by this sample does not teach the noise level
            self._ms_diff += self._k * (d * d - self._ms_diff)
        self._last = f_body_mps2
        self.l0, self.l1, self.l2 = f0, f1, f2
        return f_body_mps2
