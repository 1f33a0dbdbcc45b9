"""The FDI's reference: what the IMU says the velocity is, fitted to the vetted samples
(:class:`ReferenceFit`, shared by the three axes), and the 1σ of a dead reckoning from it.

The reference (what the IMU says the velocity is)
-------------------------------------------------
With consistent kinematics the earth-frame velocity obeys V̇ = E Γ (equations.md, "What
careful analysis adds"; Γ = f + g_body, (9)). A real autopilot's IMU and attitude are not
exact: the accelerometer reads f + b (b a body-frame bias), and its heading carries an error
δψ, which rotates the earth-frame acceleration about the down axis. To first order,

    z_j(τ) = y_j(τ) − A_j(τ) = V0_j − B_j(τ) b + δψ C_j(τ) − d L_j(τ) + n_j(τ)

with the integrals A(t) = ∫ (E f + g e_d) dt, B(t) = ∫ E dt (3×3) and C(t) = ∫ (−a_e, a_n,
0) dt kept by the vehicle (a = E f + g e_d). The last term is the measurement's lag d: a
velocity that arrives d late reads y(τ) = v(τ − d) ≈ v(τ) − d a(τ) (our ``autopilot``
profile's filtered GPS: 150 ms); L(τ) is the IMU's mean earth acceleration over the last
``LAG_WINDOW_S`` (an integral difference: no vibration noise). Unmodelled, a lag reads as a
step at every strong acceleration (a gun launch: 13 m/s² × 0.15 s = 2 m/s). θ = (V0 (3),
b (3), δψ, d) is fitted by Bayesian
linear regression over the *vetted* samples of the last ``bias_window_s`` (samples at
least ``vet_delay_s`` old that passed every test), with zero-mean priors σ_b =
``prior_bias_mps2``, σ_ψ = ``prior_yaw_rad`` and σ_d = ``prior_lag_s`` (V0 is free; d is
bounded to [0, ``max_lag_s``]). The priors keep the fit
bounded when the flight does not excite b or δψ (hover, straight flight), and the
posterior covariance P gives the prediction's own uncertainty: extrapolating an
unobserved heading error into a sudden acceleration is uncertain, and the tests say so.

    ŷ_j(t) = x_j(t) θ̂,   σ²_pred,j = x_j P x_jᵀ,   r_j = y_j − ŷ_j
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from glmav_observer.estimation.fdi_kernels import (
    fill_rows,
    normal_equations,
    predict,
    spd_inverse,
)
from glmav_observer.estimation.fdi_types import FdiConfig

#: Number of fitted parameters: V0 (3), body accelerometer bias (3), heading error (1),
#: measurement lag (1).
N_THETA = 8
#: Index of the lag (s) in θ.
LAG = 7
#: Window (s) of the lag regressor L: the IMU's mean earth acceleration over it.
LAG_WINDOW_S = 0.1
#: (The lag is a property of the link, learnt over many windows: the memory's time
#: constant and the smallest σ of the prior it gives later fits are ``FdiTuning``'s
#: ``lag_memory_s`` and ``lag_sigma_min_s``.)
#: Precision of the (free) V0 prior, 1/(m/s)²: 1/(100 m/s)², far wider than any velocity.
_V0_PRECISION = 1e-4
#: A fitted parameter is "observed" (used rather than its prior's zero mean) beyond this
#: many σ of its own (2σ: a 5 % chance that noise alone looks observed).
OBSERVED_SIGMA = 2.0

FloatArray = np.ndarray[Any, np.dtype[np.float64]]
#: One row's regressors: B(τ) flattened (9), C(τ) (3) and the earth-frame acceleration
#: L(τ) (3, the IMU's mean over the last ``LAG_WINDOW_S``).
Integrals = tuple[tuple[float, ...], tuple[float, float, float], tuple[float, float, float]]
#: The columns of :class:`ReferenceFit`'s rows as an array (:func:`.fdi_kernels.
#: fill_rows`): axis, z, weight, then the N_THETA regressors.
ROW_WIDTH = 3 + N_THETA
#: One vetted sample of :class:`ReferenceFit`: (t, axis, z_j, B(t) flat 9, C(t) 3, σ_r of
#: the axis, L(t) 3).
Row = tuple[
    float,
    int,
    float,
    tuple[float, ...],
    tuple[float, float, float],
    float,
    tuple[float, float, float],
]


def sigma_dead_reckoning_mps(cfg: FdiConfig, age_s: float) -> float:
    """1σ of a dead-reckoned velocity ``age_s`` after its last anchor (a vetted sample, a
    hand-over): √(σ0² + (σ_b t)² + q t), σ0 = ``sigma_handover_mps``, σ_b =
    ``sigma_bias_mps2`` (an accelerometer bias left over), q = ``accel_noise_density``²
    (the IMU's white noise integrated); a negative age counts as 0."""
    age = max(0.0, age_s)
    return math.sqrt(
        cfg.sigma_handover_mps**2
        + (cfg.sigma_bias_mps2 * age) ** 2
        + cfg.accel_noise_density**2 * age
    )


def dead_reckoning_age_s(cfg: FdiConfig, sigma_mps: float) -> float:
    """The inverse of :func:`sigma_dead_reckoning_mps`: the age at which the dead-reckoned
    σ reaches ``sigma_mps`` (0 at or below σ0): σ_b² t² + q t + σ0² − σ² = 0 solved for t."""
    a, b = cfg.sigma_bias_mps2**2, cfg.accel_noise_density**2
    c = cfg.sigma_handover_mps**2 - sigma_mps * sigma_mps
    if c >= 0.0:
        return 0.0
    if a == 0.0:
        return -c / b if b > 0.0 else 0.0
    return (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


@dataclass(frozen=True, slots=True)
class Reference:
    """A fitted reference: θ̂, its covariance and the integrals it is anchored at."""

    theta: tuple[float, ...]  # V0 n, e, d; b x, y, z; δψ; lag d (s)
    cov: FloatArray  # (8, 8)
    b_anchor: tuple[float, ...]  # B at the first row (9)
    c_anchor: tuple[float, float, float]  # C at the first row

    def predict(
        self, axis: int, a_int_j: float, ints: Integrals, *, lagged: bool = True
    ) -> tuple[float, float]:
        """(ŷ_j, σ_pred,j) at integrals ``ints``: the measurement (``lagged``) or the
        velocity itself (the lag term left out)."""
        return predict(
            self.theta, self.cov, self.b_anchor, self.c_anchor, axis, a_int_j, ints, lagged
        )

    @property
    def bias_body_mps2(self) -> tuple[float, float, float]:
        return (self.theta[3], self.theta[4], self.theta[5])

    def observed(self, k: int) -> float:
        """θ̂_k if the data observed it (|θ̂_k| > ``OBSERVED_SIGMA`` σ_k), else 0 (the
        prior's mean)."""
        th = self.theta[k]
        return th if th * th > OBSERVED_SIGMA**2 * max(float(self.cov[k, k]), 0.0) else 0.0

    def held(self) -> Reference:
        """This reference to hold through an isolation (its b and δψ are held as they are):
        the lag only if observed, else 0. A held parameter loses its covariance, and an
        unobserved lag from a quiet window (0.03 s, say) held into a 5 m/s² acceleration
        is a 0.15 m/s residual on a healthy axis."""
        th = list(self.theta)
        th[LAG] = self.observed(LAG)
        return Reference(tuple(th), self.cov, self.b_anchor, self.c_anchor)

    def shifted(self, axis: int, dv_mps: float) -> Reference:
        th = list(self.theta)
        th[axis] += dv_mps
        return Reference(tuple(th), self.cov, self.b_anchor, self.c_anchor)


@dataclass
class ReferenceFit:
    """The Bayesian least squares of the module docstring, shared by the three axes."""

    cfg: FdiConfig
    #: one :data:`Row` per vetted sample
    rows: deque[Row] = field(default_factory=deque)
    ref: Reference | None = None
    fitted: bool = False
    frozen_bias: bool = False
    imu_ok: bool = True
    _since_fit: int = 0
    #: what earlier windows learnt of the lag: its mean (s) and precision (1/s²)
    lag_memory_s: float = 0.0
    lag_memory_info: float = 0.0
    _t_lag_memory_s: float = -math.inf
    rows_per_axis: list[int] = field(default_factory=lambda: [0, 0, 0])
    fitted_axes: frozenset[int] = frozenset()
    #: a prior on (b x, y, z, δψ) carried over from another service's fit (a ``serve
    #: --claim`` takeover, :meth:`carry_over`): means, σ, and the vehicle time until which
    #: it replaces the config's zero-mean priors
    carried_prior: tuple[tuple[float, ...], tuple[float, ...], float] | None = None
    #: rows ever added and ever dropped (from the front): ``rows`` holds those numbered
    #: [_n_dropped, _n_added)
    _n_added: int = 0
    _n_dropped: int = 0
    #: the rows as one array (n, ROW_WIDTH), kept between fits (a row is in ~20 fits): the
    #: number of the first row it holds, and the array (:meth:`_array`)
    _rows_array: tuple[int, FloatArray] | None = None

    def carry_over(
        self,
        theta: tuple[float, ...],
        sigma: tuple[float, ...],
        t_s: float,
        until_s: float,
    ) -> None:
        """Start from what another fit learnt: ``theta``/``sigma`` = (b x, y, z, δψ, d)
        and their 1σ. b and δψ become the priors of the fits until ``until_s`` (vehicle
        time; then this fit's own window holds as much as the one it continues); the lag
        goes into the lag memory (it is a property of the link, kept as long)."""
        self.carried_prior = (tuple(theta[:4]), tuple(max(x, 1e-6) for x in sigma[:4]), until_s)
        base = 1.0 / self.cfg.prior_lag_s**2
        info = 1.0 / max(sigma[4], self.cfg.tuning.lag_sigma_min_s) ** 2 - base
        if info > 0.0:  # the prior's mean is then (memory info · memory mean) / (base + info)
            self.lag_memory_info = info
            self.lag_memory_s = theta[4] * (base + info) / info
            self._t_lag_memory_s = t_s

    def add(self, t_s: float, axis: int, z_mps: float, ints: Integrals, sigma_mps: float) -> None:
        self.rows.append((t_s, axis, z_mps, ints[0], ints[1], sigma_mps, ints[2]))
        self.rows_per_axis[axis] += 1
        self._since_fit += 1
        self._n_added += 1

    def drop_before(self, t_s: float) -> None:
        while self.rows and self.rows[0][0] < t_s:
            self.rows_per_axis[self.rows.popleft()[1]] -= 1
            self._n_dropped += 1
        self.fitted = False
        self.fitted_axes = frozenset()

    def prune_and_fit(self, t_s: float) -> None:
        t_min = t_s - self.cfg.vet_delay_s - self.cfg.bias_window_s
        rows = self.rows
        while rows and rows[0][0] < t_min:
            self.rows_per_axis[rows.popleft()[1]] -= 1
            self._n_dropped += 1
        if self._since_fit >= self.cfg.tuning.refit_rows or (
            not self.fitted and self._since_fit > 0
        ):
            new_rows = self._since_fit
            self._since_fit = 0
            self._fit(new_rows)

    def span_s(self) -> float:
        return self.rows[-1][0] - self.rows[0][0] if self.rows else 0.0

    @property
    def bias_body_mps2(self) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0) if self.ref is None else self.ref.bias_body_mps2

    def _lag_prior(self) -> tuple[float, float]:
        """(mean, precision) of the lag's prior: the config's (zero mean, σ ``prior_lag_s``)
        combined with what earlier windows learnt (``lag_memory``), at most
        1/``lag_sigma_min_s``²."""
        base = 1.0 / self.cfg.prior_lag_s**2
        info = min(base + self.lag_memory_info, 1.0 / self.cfg.tuning.lag_sigma_min_s**2)
        mean = self.lag_memory_info * self.lag_memory_s / (base + self.lag_memory_info)
        return min(max(mean, 0.0), self.cfg.max_lag_s), info

    def _remember_lag(
        self,
        theta_lag: float,
        var_lag: float,
        prior: tuple[float, float],
        t_s: float,
        fraction: float,
    ) -> None:
        """Fold this window's evidence on the lag into the memory. The window's likelihood
        alone (its posterior minus the prior it started from) is weighted by the fraction
        of its rows that are new (windows overlap: a row is in ~20 fits), and the memory
        forgets with time constant ``lag_memory_s`` (a link's lag can change)."""
        mean0, info0 = prior
        info_like = 1.0 / max(var_lag, 1e-12) - info0
        decay = math.exp(-max(t_s - self._t_lag_memory_s, 0.0) / self.cfg.tuning.lag_memory_s)
        self._t_lag_memory_s = t_s
        kept = self.lag_memory_info * decay
        if info_like <= 1.0 / self.cfg.prior_lag_s**2:
            # a window that knows less of the lag than the prior (a hover, a straight
            # line): its estimate is noise, and clipped noise would bias the memory
            self.lag_memory_info = kept
            return
        d_like = (theta_lag / var_lag - info0 * mean0) / info_like
        d_like = min(max(d_like, -self.cfg.max_lag_s), 2.0 * self.cfg.max_lag_s)
        add = fraction * info_like
        total = kept + add
        self.lag_memory_s = (kept * self.lag_memory_s + add * d_like) / total
        self.lag_memory_info = total

    def _array(self) -> FloatArray:
        """The rows as one array (n, ROW_WIDTH), :func:`.fdi_kernels.fill_rows`: those of the
        last fit still held, and the rows added since, converted once."""
        rows = self.rows
        first, end = self._n_dropped, self._n_added
        kept = self._rows_array
        if kept is not None and kept[0] <= first <= kept[0] + len(kept[1]):
            old = kept[1][first - kept[0] :]
        else:
            old = np.empty((0, ROW_WIDTH))
        k = len(old)
        arr: FloatArray = np.empty((max(len(rows), k), ROW_WIDTH))
        arr[:k] = old
        fill_rows(arr[k:], rows, self.cfg.correlation_samples)
        if not len(arr) == end - first == len(rows):
            # the counts disagree with the rows (only if ``rows`` was changed from outside
            # this class): start the array afresh from the rows as they are
            self._rows_array = None
            self._n_dropped, self._n_added = 0, len(rows)
            self.rows_per_axis = [sum(1 for r in rows if r[1] == k) for k in range(3)]
            return self._array()
        self._rows_array = (first, arr)
        return arr

    def _fit(self, new_rows: int = 0) -> None:
        rows = self.rows
        cfg = self.cfg
        if len(rows) < cfg.tuning.fit_min_rows or self.span_s() < cfg.tuning.fit_min_span_s:
            return
        n = len(rows)
        b0 = rows[0][3]
        c0 = rows[0][4]
        arr = self._array()
        # the regressors anchored at the first row: −(B_j(τ) − B_j(τ₀)) (the array holds
        # −B_j) and C_j(τ) − C_j(τ₀)
        anchor = np.array(
            [
                x
                for j in range(3)
                for x in (0.0, 0.0, 0.0, -b0[3 * j], -b0[3 * j + 1], -b0[3 * j + 2], c0[j], 0.0)
            ]
        ).reshape(3, N_THETA)
        # XᵀWX and XᵀWz in one pass over the rows (X = the rows' regressors − the anchor)
        xtwx = np.empty((N_THETA, N_THETA))
        xtwz = np.empty(N_THETA)
        normal_equations(arr, anchor, xtwx, xtwz)
        prior = np.array(
            [_V0_PRECISION] * 3
            + [1.0 / cfg.prior_bias_mps2**2] * 3
            + [1.0 / cfg.prior_yaw_rad**2, 1.0 / cfg.prior_lag_s**2]
        )
        present = [k for k in range(3) if self.rows_per_axis[k] > 0]
        old = self.ref
        lag_prior = self._lag_prior()
        if self.frozen_bias and old is not None:
            # an axis is isolated: b and δψ are held at the values of isolation (the rows of
            # the remaining axes refit their V0 only)
            prior[3:] = 1e12
            mean = np.array(old.held().theta)
        else:
            mean = np.zeros(N_THETA)
            mean[LAG], prior[LAG] = lag_prior
            carried = self.carried_prior
            if carried is not None and rows[-1][0] <= carried[2]:
                mean[3:7] = carried[0]
                prior[3:7] = 1.0 / np.square(carried[1])
        info = xtwx + np.diag(prior)
        rhs = xtwz + prior * mean
        cov: FloatArray = np.empty((N_THETA, N_THETA))
        if not spd_inverse(info, cov):  # (positive definite: priors on every parameter)
            try:
                cov = np.asarray(np.linalg.inv(info), dtype=np.float64)
            except np.linalg.LinAlgError:
                return
        theta = cov @ rhs
        if self.frozen_bias and old is not None:
            # B anchor moved: with b, δψ held, only V0 changes; keep θ's b, δψ exactly
            theta[3:] = mean[3:]
            # ... but not their uncertainty: held is not known. Consider covariance (V0
            # fitted with θ₁ = (b, δψ, d) held, θ₁ uncertain by P₁ from the fit before the
            # isolation): V0 moves with θ₁ by S = −C₀ X₀ᵀW X₁, so
            # cov = [[C₀ + S P₁ Sᵀ, S P₁], [P₁ Sᵀ, P₁]]. A held heading error then says how
            # uncertain it makes a healthy axis's prediction in the next acceleration.
            c0_v = cov[:3, :3]
            sens = -c0_v @ xtwx[:3, 3:]  # X₀ᵀW X₁
            p1 = np.asarray(old.cov[3:, 3:])
            cov = np.block([[c0_v + sens @ p1 @ sens.T, sens @ p1], [p1 @ sens.T, p1]])
        else:
            self._remember_lag(
                float(theta[LAG]),
                float(cov[LAG, LAG]),
                lag_prior,
                rows[-1][0],
                min(1.0, new_rows / n),
            )
        # bounded: a fit beyond any accelerometer's bias is not applied
        b = theta[3:6]
        nb = math.sqrt(float(b.dot(b)))  # np.linalg.norm(b), without its checks
        if nb > cfg.max_bias_mps2:
            theta[3:6] = b * (cfg.max_bias_mps2 / nb)
        # a measurement is late, never early; and no autopilot is later than max_lag_s
        theta[LAG] = min(max(float(theta[LAG]), 0.0), cfg.max_lag_s)
        if not (self.frozen_bias and old is not None) and (
            (theta[LAG] - lag_prior[0]) ** 2 <= cfg.tuning.lag_keep_sigma**2 * cov[LAG, LAG]
        ):
            # a window that does not move the lag clearly (2σ) from what was known keeps
            # the known value: its own estimate times L (the IMU's acceleration, 2 m/s² of
            # noise on a vibrating quad) would only add noise to every prediction; its
            # uncertainty stays in cov (and in σ_pred)
            theta[LAG] = lag_prior[0]
        self.ref = Reference(
            tuple(theta.tolist()),
            np.asarray(cov, dtype=np.float64),
            tuple(b0),
            (c0[0], c0[1], c0[2]),
        )
        self.fitted = True
        self.fitted_axes = frozenset(present)
