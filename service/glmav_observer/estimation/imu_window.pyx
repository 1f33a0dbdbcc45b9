"""The mean of a window of IMU differences and its σ, compiled (it runs at every sample
of the estimator's IMU, for each redundant IMU: :mod:`.imu_monitor`).

``window``: (t, (d_x, d_y, d_z)) pairs, oldest first (a deque). Two passes per axis in C
doubles, summed in the window's order: the former ``math.fsum`` passes rounded each sum
exactly, this rounds each addition (the difference is a few ulp of a σ, far below what a
threshold can tell; the golden replays compare σ within 1e-9).
"""

from libc.math cimport INFINITY, sqrt


def mean_and_sigma(window):
    """(mean per axis, σ of the mean per axis, n) of the window's differences; with fewer
    than two samples ([0, 0, 0], [inf, inf, inf], n)."""
    cdef Py_ssize_t n = len(window)
    cdef double s0 = 0.0, s1 = 0.0, s2 = 0.0, q0 = 0.0, q1 = 0.0, q2 = 0.0
    cdef double m0, m1, m2, x0, x1, x2, rn
    if n < 2:
        return [0.0, 0.0, 0.0], [INFINITY, INFINITY, INFINITY], n
    for _, d in window:
        x0, x1, x2 = d
        s0 += x0
        s1 += x1
        s2 += x2
    m0 = s0 / n
    m1 = s1 / n
    m2 = s2 / n
    for _, d in window:
        x0, x1, x2 = d
        x0 -= m0
        x1 -= m1
        x2 -= m2
        q0 += x0 * x0
        q1 += x1 * x1
        q2 += x2 * x2
    rn = sqrt(<double> n)
    return [m0, m1, m2], [sqrt(q0 / n) / rn, sqrt(q1 / n) / rn, sqrt(q2 / n) / rn], n
