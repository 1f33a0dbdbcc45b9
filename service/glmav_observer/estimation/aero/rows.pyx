"""The drag model's two recursive least-squares rows, compiled (Cython).

:class:`~glmav_observer.estimation.aero.model.DragModel` learns, at every healthy velocity
measurement, one rank-one update per body row (x, y) of θ_j and P_j = Cov(θ_j) (its
module docstring, "Learning"). That arithmetic on 5- or 6-vectors is here, on C arrays
held between calls; the decisions around it (outliers, validation, the prior put back,
the model's own tests) stay in ``model.py``.

A sample is learnt in two calls, as the model decides in between: :meth:`RowFits.terms`
(the regressors φ_j, Pφ, the one-step-ahead residual e = f_j − φᵀθ and φᵀPφ per row, and
whether the sample is an outlier) and, if the model learns it, :meth:`RowFits.commit`
(the forgetting λ, the residual and speed sums, θ and P).

Float order: every sum and product is the one ``model.py`` computed in Python floats,
in the same order, σ_f² as Python's ``** 2`` (libm's pow: :mod:`~glmav_observer.
estimation.pyfloat`) (without a control regressor the sums are written out from the first
product; with one they start from 0, as ``sum(map(mul, ...))`` did): the same doubles.
"""

from libc.math cimport fabs

from glmav_observer.estimation.pyfloat cimport py_square


cdef enum:
    #: the most parameters a row has: (c, k, k·w_n, k·w_e, q) and the cyclic gain b
    MAX_PARAM = 6


cdef class RowFits:
    """θ_j, P_j and the running sums of the two body rows (module docstring)."""

    cdef readonly int n_param
    cdef double th[2][MAX_PARAM]
    cdef double P[2][MAX_PARAM][MAX_PARAM]
    cdef double res[2]
    cdef double s1[2]
    cdef double s2[2]
    # the last sample's terms per row (terms(), read by commit())
    cdef double sj[2]
    cdef double pphi[2][MAX_PARAM]
    cdef double e[2]
    cdef double ppp[2]
    cdef double var_f[2]

    def __init__(self, int n_param, theta, cov):
        """``n_param`` 5 (drag) or 6 (with the cyclic regressor); ``theta`` (2, n) and
        ``cov`` (2, n, n) as nested sequences."""
        if n_param != 5 and n_param != 6:
            raise ValueError(f"a drag row has 5 or 6 parameters, not {n_param}")
        self.n_param = n_param
        self.set(theta, cov)
        for j in range(2):
            self.res[j] = 0.0
            self.s1[j] = 0.0
            self.s2[j] = 0.0

    def set(self, theta, cov):
        """θ (2, n) and P (2, n, n), nested sequences of floats."""
        cdef int j, a, b, n = self.n_param
        for j in range(2):
            for a in range(n):
                self.th[j][a] = theta[j][a]
                for b in range(n):
                    self.P[j][a][b] = cov[j][a][b]

    def copy(self):
        """A copy of θ, P and the running sums (the last sample's terms are not kept:
        a copy is read, never committed to, before its next ``terms``)."""
        cdef RowFits out = RowFits.__new__(RowFits)
        cdef int j, a, b, n = self.n_param
        out.n_param = n
        for j in range(2):
            out.res[j] = self.res[j]
            out.s1[j] = self.s1[j]
            out.s2[j] = self.s2[j]
            for a in range(n):
                out.th[j][a] = self.th[j][a]
                for b in range(n):
                    out.P[j][a][b] = self.P[j][a][b]
        return out

    def theta(self):
        """θ per row as lists (2, n)."""
        cdef int j, a
        return [[self.th[j][a] for a in range(self.n_param)] for j in range(2)]

    def cov(self):
        """P per row as lists (2, n, n)."""
        cdef int j, a, b
        cdef int n = self.n_param
        return [[[self.P[j][a][b] for b in range(n)] for a in range(n)] for j in range(2)]

    @property
    def res_sum(self):
        """Exponentially weighted Σ e² σ_f²/(σ_f² + φᵀPφ) per row."""
        return [self.res[0], self.res[1]]

    @property
    def s_sum(self):
        """Exponentially weighted Σ s_j (body-frame ground speed r_j·v) per row."""
        return [self.s1[0], self.s1[1]]

    @property
    def s2_sum(self):
        """Exponentially weighted Σ s_j² per row."""
        return [self.s2[0], self.s2[1]]

    def terms(
        self,
        f_body_mps2,
        e_flat,
        v_ned_mps,
        rho,
        sig_f,
        bint quadratic,
        bint trusted,
        double outlier_sigma_sq,
    ):
        """One sample's terms per row (module docstring): ``e_flat`` E row-major (9),
        ``rho`` (ρ_x, ρ_y) with the cyclic regressor (else ignored), ``sig_f`` σ_f per
        row. True if the residual of a row exceeds ``outlier_sigma_sq`` (σ units,
        squared) times its variance while ``trusted``."""
        cdef int j, a, b, n = self.n_param
        cdef double v0 = v_ned_mps[0], v1 = v_ned_mps[1], v2 = v_ned_mps[2]
        cdef double rn, re, rd, s, acc, e, ppp, var_f
        cdef double phi[MAX_PARAM]
        cdef double* pa
        cdef double* pp
        cdef double* th
        cdef bint outlier = False
        for j in range(2):
            rn = e_flat[j]
            re = e_flat[3 + j]
            rd = e_flat[6 + j]
            s = rn * v0 + re * v1 + rd * v2
            phi[0] = 1.0
            phi[1] = -s
            phi[2] = rn
            phi[3] = re
            phi[4] = (-s) * fabs(s) if quadratic else 0.0
            pp = self.pphi[j]
            th = self.th[j]
            if n == 5:  # written out from the first product, as model.py did
                for a in range(5):
                    pa = self.P[j][a]
                    pp[a] = pa[0] * phi[0] + pa[1] * phi[1] + pa[2] * phi[2] + pa[3] * phi[3] + pa[4] * phi[4]
                e = <double>f_body_mps2[j] - (th[0] + th[1] * phi[1] + th[2] * rn + th[3] * re + th[4] * phi[4])
                ppp = phi[0] * pp[0] + phi[1] * pp[1] + phi[2] * pp[2] + phi[3] * pp[3] + phi[4] * pp[4]
            else:  # sums from 0, as sum(map(mul, ...)) did
                phi[5] = rho[j]
                for a in range(n):
                    pa = self.P[j][a]
                    acc = 0.0
                    for b in range(n):
                        acc = acc + pa[b] * phi[b]
                    pp[a] = acc
                acc = 0.0
                for b in range(n):
                    acc = acc + th[b] * phi[b]
                e = <double>f_body_mps2[j] - acc
                ppp = 0.0
                for b in range(n):
                    ppp = ppp + phi[b] * pp[b]
            var_f = py_square(sig_f[j])  # sig_f[j] ** 2
            if trusted and e * e > outlier_sigma_sq * (var_f + ppp):
                outlier = True
            self.sj[j] = s
            self.e[j] = e
            self.ppp[j] = ppp
            self.var_f[j] = var_f
        return outlier

    def quad_form(self, int j, phi):
        """φᵀ P_j φ of row ``j`` (φ: n floats), summed as Σ_a φ_a (Σ_b P_ab φ_b), each sum
        from 0 (as Python's ``sum`` of the products)."""
        cdef int a, b, n = self.n_param
        cdef double x[MAX_PARAM]
        cdef double inner, acc = 0.0
        if not 0 <= j < 2 or len(phi) != n:
            raise ValueError(f"quad_form: row 0 or 1 and {n} regressors")
        for a in range(n):
            x[a] = phi[a]
        for a in range(n):
            inner = 0.0
            for b in range(n):
                inner = inner + self.P[j][a][b] * x[b]
            acc = acc + x[a] * inner
        return acc

    def commit(self, double lam):
        """Learn the sample of the last :meth:`terms` with forgetting ``lam``: the sums,
        then Λ ← λΛ + φφᵀ/σ_f² in covariance form (P/λ and the Sherman-Morrison
        rank-one update; the prior's (1 − λ)Λ₀ is put back by the model)."""
        cdef int j, a, b, n = self.n_param
        cdef double inv_l = 1.0 / lam
        cdef double e, var_f, ppp, s, denom, g, ge, c, ca
        cdef double* pp
        cdef double* row
        for j in range(2):
            e = self.e[j]
            var_f = self.var_f[j]
            ppp = self.ppp[j]
            s = self.sj[j]
            pp = self.pphi[j]
            self.res[j] = lam * self.res[j] + e * e * var_f / (var_f + ppp)
            self.s1[j] = lam * self.s1[j] + s
            self.s2[j] = lam * self.s2[j] + s * s
            denom = var_f + ppp * inv_l
            g = inv_l / denom  # the gain K = g · Pφ
            ge = g * e
            for a in range(n):
                self.th[j][a] = self.th[j][a] + ge * pp[a]
            c = inv_l * inv_l / denom
            for a in range(n):
                ca = c * pp[a]
                row = self.P[j][a]
                for b in range(n):
                    row[b] = row[b] * inv_l - ca * pp[b]
