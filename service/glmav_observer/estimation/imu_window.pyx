"""The window of one redundant IMU's differences to IMU 1, compiled (it runs at every
sample of the estimator's IMU, for each redundant IMU: :mod:`.imu_monitor`).

:class:`PairWindow` keeps the secondary instance's latest sample, the differences
d = f_k − f_1 (body FRD, m/s²) at IMU 1's samples over the last ``window_s`` in a ring of C
doubles, and the pair's baseline. The window's mean and its σ are two passes per axis in C
doubles, summed in the window's order (the former ``math.fsum`` passes rounded each sum
exactly, this rounds each addition: a few ulp of a σ, far below what a threshold can tell;
the golden replays compare σ within 1e-9).
"""

from cpython.mem cimport PyMem_Free, PyMem_Malloc
from libc.math cimport INFINITY, fabs, sqrt

DEF START_CAPACITY = 64


cdef class PairWindow:
    """The differences of one secondary IMU to IMU 1 over the window, and its baseline."""

    cdef double *_t
    cdef double *_d
    cdef Py_ssize_t _cap, _head, _n
    cdef double _b[3]
    cdef bint _has_baseline
    cdef public double t_last_s
    cdef double _f_last[3]

    def __cinit__(self):
        self._cap = START_CAPACITY
        self._t = <double *> PyMem_Malloc(self._cap * sizeof(double))
        self._d = <double *> PyMem_Malloc(3 * self._cap * sizeof(double))
        if self._t is NULL or self._d is NULL:
            raise MemoryError()
        self._head = 0
        self._n = 0
        self._has_baseline = False
        self.t_last_s = -INFINITY
        self._f_last[0] = self._f_last[1] = self._f_last[2] = 0.0

    def __dealloc__(self):
        PyMem_Free(self._t)
        PyMem_Free(self._d)

    def __len__(self):
        return self._n

    # ------------------------------------------------------------------ copy / pickle
    def __reduce__(self):
        """The window, the baseline and the secondary's last sample (for copy.deepcopy
        and pickle)."""
        cdef Py_ssize_t i, j
        rows = []
        for i in range(self._n):
            j = self._at(i)
            rows.append((self._t[j], self._d[3 * j], self._d[3 * j + 1], self._d[3 * j + 2]))
        return (PairWindow, (), (rows, self.baseline, self.t_last_s, self.f_last))

    def __setstate__(self, state):
        rows, baseline, t_last_s, f_last = state
        self._head = 0
        self._n = 0
        for t, d0, d1, d2 in rows:
            if self._n == self._cap:
                self._grow()
            self._t[self._n] = t
            self._d[3 * self._n] = d0
            self._d[3 * self._n + 1] = d1
            self._d[3 * self._n + 2] = d2
            self._n += 1
        self._has_baseline = baseline is not None
        if self._has_baseline:
            self._b[0], self._b[1], self._b[2] = baseline
        self.note(t_last_s, f_last)

    cdef inline Py_ssize_t _at(self, Py_ssize_t i):
        """The ring index of the window's i-th sample (0: the oldest)."""
        i += self._head
        return i - self._cap if i >= self._cap else i

    cdef void _grow(self) except *:
        cdef Py_ssize_t cap = 2 * self._cap, i, j
        cdef double *t = <double *> PyMem_Malloc(cap * sizeof(double))
        cdef double *d = <double *> PyMem_Malloc(3 * cap * sizeof(double))
        if t is NULL or d is NULL:
            PyMem_Free(t)
            PyMem_Free(d)
            raise MemoryError()
        for i in range(self._n):
            j = self._at(i)
            t[i] = self._t[j]
            d[3 * i] = self._d[3 * j]
            d[3 * i + 1] = self._d[3 * j + 1]
            d[3 * i + 2] = self._d[3 * j + 2]
        PyMem_Free(self._t)
        PyMem_Free(self._d)
        self._t, self._d, self._cap, self._head = t, d, cap, 0

    def note(self, double t_s, f_body_mps2):
        """The secondary instance's sample at ``t_s``."""
        self.t_last_s = t_s
        self._f_last[0], self._f_last[1], self._f_last[2] = f_body_mps2

    @property
    def baseline(self):
        """The baseline [x, y, z] (m/s²), or None before the first full window."""
        if not self._has_baseline:
            return None
        return [self._b[0], self._b[1], self._b[2]]

    @property
    def f_last(self):
        return (self._f_last[0], self._f_last[1], self._f_last[2])

    def step(
        self, double t_s, f_body_mps2, double window_s, double max_age_s,
        Py_ssize_t min_samples, double min_fill,
    ):
        """IMU 1's sample ``f_body_mps2`` at ``t_s``: the difference enters the window, the
        samples ``window_s`` old leave it. Returns (deviation of the mean from the
        baseline, σ of the mean), both [x, y, z], once the window holds ``min_samples``
        and spans ``min_fill`` of ``window_s`` (the baseline starts at the first such
        mean); None before, and with the window emptied when the secondary's last sample
        is older than ``max_age_s`` (a stream that stopped)."""
        cdef double f0, f1, f2, m0, m1, m2, x0, x1, x2, s0 = 0.0, s1 = 0.0, s2 = 0.0
        cdef double q0 = 0.0, q1 = 0.0, q2 = 0.0, rn
        cdef Py_ssize_t i, j, n
        if t_s - self.t_last_s > max_age_s:
            self._head = 0
            self._n = 0
            return None
        f0, f1, f2 = f_body_mps2
        if self._n == self._cap:
            self._grow()
        j = self._at(self._n)
        self._t[j] = t_s
        self._d[3 * j] = self._f_last[0] - f0
        self._d[3 * j + 1] = self._f_last[1] - f1
        self._d[3 * j + 2] = self._f_last[2] - f2
        self._n += 1
        while self._n and self._t[self._head] <= t_s - window_s:
            self._head += 1
            if self._head == self._cap:
                self._head = 0
            self._n -= 1
        n = self._n
        if n < 2 or n < min_samples or t_s - self._t[self._head] < min_fill * window_s:
            return None
        for i in range(n):
            j = self._at(i)
            s0 += self._d[3 * j]
            s1 += self._d[3 * j + 1]
            s2 += self._d[3 * j + 2]
        m0 = s0 / n
        m1 = s1 / n
        m2 = s2 / n
        for i in range(n):
            j = self._at(i)
            x0 = self._d[3 * j] - m0
            x1 = self._d[3 * j + 1] - m1
            x2 = self._d[3 * j + 2] - m2
            q0 += x0 * x0
            q1 += x1 * x1
            q2 += x2 * x2
        rn = sqrt(<double> n)
        if not self._has_baseline:
            self._b[0], self._b[1], self._b[2] = m0, m1, m2
            self._has_baseline = True
        return (
            [m0 - self._b[0], m1 - self._b[1], m2 - self._b[2]],
            [sqrt(q0 / n) / rn, sqrt(q1 / n) / rn, sqrt(q2 / n) / rn],
        )

    def learn_baseline(self, dev, double tau_s):
        """The baseline follows the window's mean (``dev`` its deviation from it) by one
        step of time constant ``tau_s`` over the window's last sample interval."""
        cdef double g
        if not self._has_baseline or self._n == 0:
            return
        g = 0.0
        if self._n >= 2:
            g = (self._t[self._at(self._n - 1)] - self._t[self._at(self._n - 2)]) / tau_s
        self._b[0] = self._b[0] + g * dev[0]
        self._b[1] = self._b[1] + g * dev[1]
        self._b[2] = self._b[2] + g * dev[2]

    def onset(self, double floor_mps2):
        """The time of the window's first difference beyond ``floor_mps2`` from the baseline
        on any axis; +inf if none (or no baseline)."""
        cdef Py_ssize_t i, j
        if not self._has_baseline:
            return INFINITY
        for i in range(self._n):
            j = self._at(i)
            if (
                fabs(self._d[3 * j] - self._b[0]) > floor_mps2
                or fabs(self._d[3 * j + 1] - self._b[1]) > floor_mps2
                or fabs(self._d[3 * j + 2] - self._b[2]) > floor_mps2
            ):
                return self._t[j]
        return INFINITY


def deviation_test(devs, double floor_mps2, double k_sigma, double end_fraction):
    """The pairs' deviations ``devs`` [(deviation [x, y, z], σ [x, y, z]), ...] against the
    threshold per axis, max(``floor_mps2``, ``k_sigma`` · the largest σ of that axis):
    (threshold [x, y, z], a deviation exceeds it, every deviation is below
    ``end_fraction`` of it, the σ of the pair whose largest σ is largest (the first of
    equals))."""
    cdef double thr[3]
    cdef double s, top = -INFINITY, best
    cdef Py_ssize_t a
    cdef bint exceeds = False, quiet = True
    sig_top = None
    thr[0] = thr[1] = thr[2] = -INFINITY
    for m, sig in devs:
        best = -INFINITY
        for a in range(3):
            s = sig[a]
            if s > thr[a]:
                thr[a] = s
            if s > best:
                best = s
        if sig_top is None or best > top:
            top = best
            sig_top = sig
    for a in range(3):
        s = k_sigma * thr[a]
        thr[a] = s if s > floor_mps2 else floor_mps2
    for m, _ in devs:
        for a in range(3):
            s = fabs(<double> m[a])
            if s > thr[a]:
                exceeds = True
            if not s < end_fraction * thr[a]:
                quiet = False
    return [thr[0], thr[1], thr[2]], exceeds, quiet, sig_top
