"""The arithmetic of the FDI per measurement, compiled (Cython).

Kernels that every velocity measurement runs (three times: once per NED axis), on a
handful of floats each; the logic that reads them stays in Python (:mod:`.fdi_axis`,
:mod:`.fdi_reference`):

- :func:`predict`: the reference's prediction of one axis and its σ,
  ŷ_j = A_j + x_j θ̂ and σ²_pred = x_j P x_jᵀ (:meth:`Reference.predict`);
- :func:`residual_ratios`: the bias and noise test ratios of the recent residuals
  (:meth:`AxisMonitor._ratios`): medians of up to ``noise_samples + 1`` floats;
- :func:`fill_rows`: the reference fit's new vetted rows as rows of its array
  (:meth:`ReferenceFit._array`);
- :func:`normal_equations`: the fit's XᵀWX and XᵀWz from that array, the anchor taken
  off each row on the way, and :func:`spd_inverse`, its information matrix inverted by
  Cholesky (:meth:`ReferenceFit._fit`).

Float order. ŷ sums x_k θ̂_k left to right from 0, as ``sum(map(mul, x, θ))`` did: the
same doubles. The medians select and average as ``statistics.median`` does (the mean of
the two middle values for an even count), and squares are libm's pow, as Python's
``** 2`` is (:func:`~glmav_observer.estimation.pyfloat.py_square`): the same doubles.
σ²_pred = Σ_j (Σ_i x_i P_ij) x_j is summed in that order; numpy's ``x @ P @ x`` went
through OpenBLAS (fused multiply-adds, its own blocking), so σ_pred may differ from the
former value in its last bit (every record of the corpus replays is unchanged by it).
XᵀWX and XᵀWz are summed over the rows in order, each entry on its own; numpy's
``(X.T * w) @ X`` went through OpenBLAS too, and ``numpy.linalg.inv`` through LAPACK's
LU, so θ̂ and its covariance may differ in their last bits.
"""

from libc.math cimport fabs, isfinite, sqrt, NAN

from glmav_observer.estimation.pyfloat cimport py_square

#: The windows' largest size (``bias_samples``, ``noise_samples + 1``, ``own_noise_history``):
#: a window longer than this is refused with a ValueError, never overrun.
cdef enum:
    MAX_WINDOW = 256


cdef double _median(double* buf, Py_ssize_t n) noexcept:
    """``statistics.median`` of buf[0:n] (n ≥ 1; sorts buf in place)."""
    cdef Py_ssize_t i, k
    cdef double x
    for i in range(1, n):  # insertion sort: n is a dozen
        x = buf[i]
        k = i - 1
        while k >= 0 and buf[k] > x:
            buf[k + 1] = buf[k]
            k -= 1
        buf[k + 1] = x
    if n % 2 == 1:
        return buf[n // 2]
    return (buf[n // 2 - 1] + buf[n // 2]) / 2.0


cdef Py_ssize_t _tail(object seq, Py_ssize_t n, double* out) except -1:
    """The last min(n, len(seq)) floats of ``seq`` (a deque or list) into out, in order
    (read from the end: no copy of the window); their count."""
    cdef Py_ssize_t size = len(seq)
    cdef Py_ssize_t m = n if n < size else size
    cdef Py_ssize_t i
    if m > MAX_WINDOW:
        raise ValueError(f"an FDI window of {m} samples exceeds {MAX_WINDOW}")
    it = reversed(seq)
    for i in range(m - 1, -1, -1):
        out[i] = <double>next(it)
    return m


def residual_ratios(
    resid,
    d2y_sq,
    Py_ssize_t bias_samples,
    Py_ssize_t noise_samples,
    double bias_threshold_mps,
    double sigma_r_mps,
    double var_d2y_mps2,
    double noise_ratio_threshold,
    double chi2_1_median,
):
    """(bias ratio, noise ratio) of an axis's recent residuals ``resid`` and the squared
    second differences of its measurement ``d2y_sq``, ``chi2_1_median`` the median of χ²₁;
    NaN where too few
    (:meth:`~glmav_observer.estimation.fdi_axis.AxisMonitor._ratios`)."""
    cdef double buf[MAX_WINDOW]
    cdef double d2[MAX_WINDOW]
    cdef Py_ssize_t m, i
    cdef double bias = NAN, noise = NAN, nominal, own
    m = _tail(resid, bias_samples, buf)
    if m == bias_samples:
        bias = fabs(_median(buf, m)) / bias_threshold_mps
    m = _tail(resid, noise_samples + 1, buf)
    if m == noise_samples + 1:
        for i in range(noise_samples):
            d2[i] = py_square(buf[i + 1] - buf[i])
        nominal = 2.0 * py_square(sigma_r_mps) * chi2_1_median
        noise = _median(d2, noise_samples) / nominal / noise_ratio_threshold
        # the measurement's own noise: a noisy residual is a noisy measurement only if
        # the measurement itself is noisy (AxisMonitor._own_noise_ratio)
        m = _tail(d2y_sq, noise_samples, buf)
        if m == noise_samples:
            own = _median(buf, m) / (var_d2y_mps2 * chi2_1_median) / noise_ratio_threshold
            if isfinite(own) and own < noise:
                noise = own
    return bias, noise


def predict(
    theta,
    const double[:, ::1] cov,
    b_anchor,
    c_anchor,
    Py_ssize_t axis,
    double a_int_j,
    ints,
    bint lagged,
):
    """(ŷ_j, σ_pred,j) of :meth:`~glmav_observer.estimation.fdi_reference.Reference.
    predict`: the regressors x_j of axis ``axis`` at ``ints`` = (B flat 9, C, L), the lag's
    left out unless ``lagged``."""
    cdef double x[8]
    cdef double th[8]
    cdef double mean = 0.0, var = 0.0, row
    cdef Py_ssize_t i, j, k = 3 * axis
    b_int, c_int, l_now = ints
    if cov.shape[0] != 8 or cov.shape[1] != 8 or len(theta) != 8 or not 0 <= axis < 3:
        raise ValueError("predict needs θ (8), P (8×8) and an axis 0-2")
    for i in range(8):
        th[i] = theta[i]
        x[i] = 0.0
    x[axis] = 1.0
    x[3] = -(<double>b_int[k] - <double>b_anchor[k])
    x[4] = -(<double>b_int[k + 1] - <double>b_anchor[k + 1])
    x[5] = -(<double>b_int[k + 2] - <double>b_anchor[k + 2])
    x[6] = <double>c_int[axis] - <double>c_anchor[axis]
    x[7] = -(<double>l_now[axis]) if lagged else 0.0
    for i in range(8):
        mean += x[i] * th[i]
    mean = a_int_j + mean
    for j in range(8):
        row = 0.0
        for i in range(8):
            row += x[i] * cov[i, j]
        var += row * x[j]
    # max(var, 0.0) as Python's max: var unless 0 is greater (NaN and −0.0 kept)
    return mean, sqrt(0.0 if 0.0 > var else var)


def fill_rows(double[:, ::1] out, rows, double correlation_samples):
    """The last ``len(out)`` rows of ``rows`` (:class:`~glmav_observer.estimation.
    fdi_reference.ReferenceFit`'s ``Row`` tuples: t, axis j, z_j, B flat 9, C, σ, L) as
    rows of ``out`` (ROW_WIDTH = 11 columns): j, z_j, the weight 1/σ²/``correlation_samples``
    and the regressors before the anchor is taken off: V0's indicator (3), −B_j(τ) (3),
    C_j(τ), −L_j(τ) (:meth:`ReferenceFit._fit` subtracts the first row's −B_j and C_j:
    −B_j(τ) − (−B_j(τ₀)) is −(B_j(τ) − B_j(τ₀)) to the bit, rounding being symmetric)."""
    cdef Py_ssize_t m = out.shape[0], i, j, k
    cdef double sigma
    if out.shape[1] != 11 or m > len(rows):
        raise ValueError(f"fill_rows: {m} rows of 11 asked, {len(rows)} held")
    it = reversed(rows)
    for i in range(m - 1, -1, -1):
        _, axis, z, b_int, c_int, sigma, l_now = next(it)
        j = axis
        if not 0 <= j < 3:
            raise ValueError(f"a reference row's axis is 0-2, not {j}")
        k = 3 * j
        out[i, 0] = j
        out[i, 1] = z
        out[i, 2] = 1.0 / py_square(sigma) / correlation_samples
        out[i, 3] = 1.0 if j == 0 else 0.0
        out[i, 4] = 1.0 if j == 1 else 0.0
        out[i, 5] = 1.0 if j == 2 else 0.0
        out[i, 6] = -(<double>b_int[k])
        out[i, 7] = -(<double>b_int[k + 1])
        out[i, 8] = -(<double>b_int[k + 2])
        out[i, 9] = c_int[j]
        out[i, 10] = -(<double>l_now[j])


def normal_equations(
    const double[:, ::1] arr, const double[:, ::1] anchor, double[:, ::1] info,
    double[::1] rhs,
):
    """The reference fit's data terms (:meth:`ReferenceFit._fit`): with row i of ``arr``
    (:func:`fill_rows`: axis j, z, w, then the 8 regressors) and x_i = arr[i, 3:] −
    ``anchor[j]`` (the first row's −B_j and C_j taken off), ``info`` = Σ w_i x_i x_iᵀ
    (XᵀWX, 8 × 8, symmetric) and ``rhs`` = Σ w_i z_i x_i (XᵀWz), without forming X."""
    cdef Py_ssize_t n = arr.shape[0], i, j, k, l
    cdef double x[8]
    cdef double w, z, wx
    if arr.shape[1] != 11 or anchor.shape[0] != 3 or anchor.shape[1] != 8:
        raise ValueError("normal_equations: rows of 11 and an anchor of 3 x 8 expected")
    if info.shape[0] != 8 or info.shape[1] != 8 or rhs.shape[0] != 8:
        raise ValueError("normal_equations: info is 8 x 8 and rhs 8")
    for k in range(8):
        rhs[k] = 0.0
        for l in range(8):
            info[k, l] = 0.0
    for i in range(n):
        j = <Py_ssize_t>arr[i, 0]
        if not 0 <= j < 3:
            raise ValueError(f"a reference row's axis is 0-2, not {j}")
        z = arr[i, 1]
        w = arr[i, 2]
        for k in range(8):
            x[k] = arr[i, 3 + k] - anchor[j, k]
        for k in range(8):
            wx = w * x[k]
            rhs[k] += wx * z
            for l in range(k, 8):
                info[k, l] += wx * x[l]
    for k in range(8):
        for l in range(k):
            info[k, l] = info[l, k]


def spd_inverse(const double[:, ::1] a, double[:, ::1] out):
    """``out`` = a⁻¹ for a symmetric positive definite ``a`` (n × n, n ≤ 16), by its
    Cholesky factor L: a⁻¹ = L⁻ᵀ L⁻¹. Returns False, ``out`` undefined, when a pivot is
    not positive and finite (not positive definite to working precision: the caller
    falls back to a general inverse)."""
    cdef Py_ssize_t n = a.shape[0], i, j, k
    cdef double L[16][16]
    cdef double M[16][16]
    cdef double acc
    if n > 16 or a.shape[1] != n or out.shape[0] != n or out.shape[1] != n:
        raise ValueError("spd_inverse: square matrices of at most 16 x 16 expected")
    for j in range(n):  # L, column by column (a's lower triangle)
        acc = a[j, j]
        for k in range(j):
            acc -= L[j][k] * L[j][k]
        if not (acc > 0.0 and isfinite(acc)):
            return False
        L[j][j] = sqrt(acc)
        for i in range(j + 1, n):
            acc = a[i, j]
            for k in range(j):
                acc -= L[i][k] * L[j][k]
            L[i][j] = acc / L[j][j]
    for j in range(n):  # M = L⁻¹ (lower triangular), column j by forward substitution
        for i in range(j):
            M[i][j] = 0.0
        M[j][j] = 1.0 / L[j][j]
        for i in range(j + 1, n):
            acc = 0.0
            for k in range(j, i):
                acc -= L[i][k] * M[k][j]
            M[i][j] = acc / L[i][i]
    for i in range(n):  # out = Mᵀ M, symmetric
        for j in range(i, n):
            acc = 0.0
            for k in range(j, n):
                acc += M[k][i] * M[k][j]
            out[i, j] = acc
            out[j, i] = acc
    return True
