"""Fault detection and isolation (FDI) of the velocity measurement, one NED axis at a time.

Pure computation (no I/O): the vehicle estimator feeds it the earth-frame integrals of the
IMU and every velocity measurement; it returns, per axis, whether the sample may be used,
the residual and its test ratio, and isolation/recovery events. Docs: docs/observer.md,
"Fault isolation".

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

Residual scale from the data. σ_r,j, the spread of vetted residuals of axis j (a running
mean of r², winsorised at 4σ, over ~``scale_samples`` samples, floored at
``sigma_floor_mps``), starts at ``sigma_meas_mps`` and adapts to what the vehicle sends: an
autopilot's filtered velocity, a vibrating IMU, a slow stream. Every test threshold is a
multiple of s_j = √(σ_r,j² + σ²_pred,j), never a number tuned on one simulator.

Tests (thresholds in :class:`FdiConfig`):

- dropout: ``dropout_samples`` consecutive NaN samples;
- freeze: ``freeze_repeats`` exact repeats of the previous value, if the stream seldom
  repeats (fewer than ``freeze_repeat_rate`` of its healthy samples: an EKF's output, a
  noisy sensor) or the IMU says the axis's velocity changed by more than
  ``freeze_motion_mps`` since that value was first seen (a noise-free or coarse GPS
  repeats its value in a hover);
- bias: |median of the last ``bias_samples`` residuals| > max(``bias_threshold_mps``,
  ``bias_sigma`` · s_j) (the median: one outlier cannot move it);
- noise: median of the last ``noise_samples`` squared successive differences over its
  nominal 2σ_r²·0.4549 (median of χ²₁) beyond ``noise_ratio_threshold``.

Accelerometer faults are not velocity faults. Before a bias is isolated on axis j, two
explanations of the recent residuals of *all three* axes since a change time t_c are
compared (:func:`classify_change`): a velocity step on axis j alone (r_j = β) and an
accelerometer-bias step in body axes, which shows in every earth axis and rotates with the
attitude (r_k = −(B_k(τ) − B_k(t_c)) Δb, a ramp). The model with the lower BIC wins. An
accelerometer change re-anchors the reference at t_c (``accel_bias`` event with Δb) and
isolates no velocity axis.

Hysteresis: bias and noise must fail ``k_isolate`` samples in a row; a sample beyond
``gate_sigma`` · s_j is kept out of ``full`` meanwhile. Recovery: the axis must pass every
test against the frozen dead reckoning for ``recovery_s``.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from glmav_observer.records import NED_AXES, AxisName, FaultEvent

#: Samples of an axis before a candidate change time (classify_change: a step needs a before).
MIN_PRE_SAMPLES = 5
#: Vetted samples of a recovered axis before its prediction comes from the live fit again.
REARM_ROWS = 20
#: Median of the χ² distribution with one degree of freedom.
CHI2_1_MEDIAN = 0.45494
#: Number of fitted parameters: V0 (3), body accelerometer bias (3), heading error (1),
#: measurement lag (1).
N_THETA = 8
#: Index of the lag (s) in θ.
LAG = 7
#: A residual isolation is withdrawn when the residual against the dead reckoning ramps
#: faster than this (m/s², beyond 3σ of the slope) over the last RAMP_WINDOW_S: a velocity
#: sensor's fault is an offset or noise around the truth; a ramp is the IMU's path (an
#: attitude estimator lost in a ballistic climb) drifting, more than any accelerometer
#: bias the fit leaves (prior 0.3 m/s²).
RAMP_LIMIT_MPS2 = 0.5
RAMP_WINDOW_S = 1.0
#: Window (s) of the lag regressor L: the IMU's mean earth acceleration over it.
LAG_WINDOW_S = 0.1
#: The lag is a property of the link, learnt over many windows: the memory's time
#: constant (s), and the smallest σ of the prior it gives later fits (a lag can change).
LAG_MEMORY_S = 120.0
LAG_SIGMA_MIN_S = 0.02
#: Precision of the (free) V0 prior, 1/(m/s)²: 1/(100 m/s)².
_V0_PRECISION = 1e-4

FloatArray = np.ndarray[Any, np.dtype[np.float64]]
#: One row's regressors: B(τ) flattened (9), C(τ) (3) and the earth-frame acceleration
#: L(τ) (3, the IMU's mean over the last ``LAG_WINDOW_S``).
Integrals = tuple[tuple[float, ...], tuple[float, float, float], tuple[float, float, float]]


class AxisState(Enum):
    """Health of one velocity axis (HealthRecord ``axis_state``)."""

    WARMUP = "warmup"  # no vetted reference yet: only dropout and freeze are tested
    OK = "ok"
    SUSPECT = "suspect"  # a test fails, not yet k samples in a row
    FAULTY = "faulty"  # isolated
    RECOVERING = "recovering"  # isolated, healthy again for less than recovery_s


#: Fault kinds decided by comparing the measurement with the IMU (revisable when the IMU
#: itself is found at fault); dropout, freeze and unaided are seen in the measurement alone.
RESIDUAL_KINDS = frozenset({"bias", "noise"})


class FaultKind(Enum):
    DROPOUT = "dropout"
    FREEZE = "freeze"
    BIAS = "bias"
    NOISE = "noise"
    UNAIDED = "unaided"  # the autopilot says this velocity is not aided (GPS lost)


@dataclass(frozen=True, slots=True)
class FdiConfig:
    """FDI settings (``[fdi]`` of ``configs/service.toml``; all documented there)."""

    sigma_meas_mps: float = 0.05
    sigma_floor_mps: float = 0.02
    scale_samples: int = 250
    vet_delay_s: float = 0.6
    bias_window_s: float = 4.0
    warmup_s: float = 1.5
    gate_sigma: float = 5.0
    dropout_samples: int = 2
    missing_timeout_s: float = 0.5
    freeze_repeats: int = 3
    #: the IMU-predicted change of an axis since its value was first seen beyond which a
    #: repeat of that value counts towards a freeze
    freeze_motion_mps: float = 0.1
    #: a stream that repeats its value less often than this (fraction of samples) seldom
    #: repeats: exact repeats alone are a freeze
    freeze_repeat_rate: float = 0.02
    bias_samples: int = 6
    bias_threshold_mps: float = 0.15
    bias_sigma: float = 5.0
    noise_samples: int = 12
    noise_ratio_threshold: float = 12.0
    k_isolate: int = 3
    recovery_s: float = 2.0
    sigma_handover_mps: float = 0.03
    sigma_bias_mps2: float = 0.03
    accel_noise_density: float = 4e-3
    min_imu_rate_hz: float = 5.0
    prior_bias_mps2: float = 0.3
    prior_yaw_rad: float = 0.1
    #: σ of the measurement-lag prior (zero mean): a GPS velocity is 0.1-0.2 s late
    #: unless the autopilot compensates it (ArduPilot's and PX4's EKFs do)
    prior_lag_s: float = 0.1
    max_lag_s: float = 0.5
    #: rows of one axis per independent sample: an autopilot's velocity is filtered, its
    #: errors correlated over a few samples (P is inflated by this factor)
    correlation_samples: float = 5.0
    max_bias_mps2: float = 2.0
    change_window_s: float = 1.5


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
class AxisVerdict:
    """What the FDI says about one axis after one measurement."""

    use: bool  # feed this sample to the observers that measure the axis
    residual_mps: float  # NaN if not computable
    test_ratio: float  # max over the tests of statistic/threshold; > 1 fails
    state: AxisState


@dataclass(frozen=True, slots=True)
class Reference:
    """A fitted reference: θ̂, its covariance and the integrals it is anchored at."""

    theta: tuple[float, ...]  # V0 n, e, d; b x, y, z; δψ; lag d (s)
    cov: FloatArray  # (8, 8)
    b_anchor: tuple[float, ...]  # B at the first row (9)
    c_anchor: tuple[float, float, float]  # C at the first row

    def regressors(self, axis: int, ints: Integrals) -> list[float]:
        b_int, c_int, l_now = ints
        k = 3 * axis
        x = [0.0] * N_THETA
        x[axis] = 1.0
        x[3] = -(b_int[k] - self.b_anchor[k])
        x[4] = -(b_int[k + 1] - self.b_anchor[k + 1])
        x[5] = -(b_int[k + 2] - self.b_anchor[k + 2])
        x[6] = c_int[axis] - self.c_anchor[axis]
        x[LAG] = -l_now[axis]
        return x

    def predict(
        self, axis: int, a_int_j: float, ints: Integrals, *, lagged: bool = True
    ) -> tuple[float, float]:
        """(ŷ_j, σ_pred,j) at integrals ``ints``: the measurement (``lagged``) or the
        velocity itself (the lag term left out)."""
        x = self.regressors(axis, ints)
        if not lagged:
            x[LAG] = 0.0
        mean = a_int_j + sum(xi * ti for xi, ti in zip(x, self.theta, strict=True))
        xv = np.asarray(x)
        var = float(xv @ self.cov @ xv)
        return mean, math.sqrt(max(var, 0.0))

    @property
    def bias_body_mps2(self) -> tuple[float, float, float]:
        return (self.theta[3], self.theta[4], self.theta[5])

    def observed(self, k: int) -> float:
        """θ̂_k if the data observed it (|θ̂_k| > 2σ_k), else 0 (the prior's mean)."""
        th = self.theta[k]
        return th if th * th > 4.0 * max(float(self.cov[k, k]), 0.0) else 0.0

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
    #: rows (t, axis, z_j, B(t) flat 9, C(t) 3, σ_r of the axis): one per vetted sample
    rows: deque[
        tuple[
            float,
            int,
            float,
            tuple[float, ...],
            tuple[float, float, float],
            float,
            tuple[float, float, float],
        ]
    ] = field(default_factory=deque)
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
        info = 1.0 / max(sigma[4], LAG_SIGMA_MIN_S) ** 2 - base
        if info > 0.0:  # the prior's mean is then (memory info · memory mean) / (base + info)
            self.lag_memory_info = info
            self.lag_memory_s = theta[4] * (base + info) / info
            self._t_lag_memory_s = t_s

    def add(self, t_s: float, axis: int, z_mps: float, ints: Integrals, sigma_mps: float) -> None:
        self.rows.append((t_s, axis, z_mps, ints[0], ints[1], sigma_mps, ints[2]))
        self.rows_per_axis[axis] += 1
        self._since_fit += 1

    def drop_before(self, t_s: float) -> None:
        while self.rows and self.rows[0][0] < t_s:
            self.rows_per_axis[self.rows.popleft()[1]] -= 1
        self.fitted = False
        self.fitted_axes = frozenset()

    def prune_and_fit(self, t_s: float) -> None:
        t_min = t_s - self.cfg.vet_delay_s - self.cfg.bias_window_s
        rows = self.rows
        while rows and rows[0][0] < t_min:
            self.rows_per_axis[rows.popleft()[1]] -= 1
        if self._since_fit >= 15 or (not self.fitted and self._since_fit > 0):
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
        combined with what earlier windows learnt (``lag_memory``), at most 1/LAG_SIGMA_MIN²."""
        base = 1.0 / self.cfg.prior_lag_s**2
        info = min(base + self.lag_memory_info, 1.0 / LAG_SIGMA_MIN_S**2)
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
        forgets with time constant LAG_MEMORY_S (a link's lag can change)."""
        mean0, info0 = prior
        info_like = 1.0 / max(var_lag, 1e-12) - info0
        decay = math.exp(-max(t_s - self._t_lag_memory_s, 0.0) / LAG_MEMORY_S)
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

    def _fit(self, new_rows: int = 0) -> None:
        rows = self.rows
        if len(rows) < 12 or self.span_s() < 1.0:
            return
        cfg = self.cfg
        n = len(rows)
        b0 = rows[0][3]
        c0 = rows[0][4]
        axes = np.fromiter((r[1] for r in rows), dtype=np.intp, count=n)
        z = np.fromiter((r[2] for r in rows), dtype=np.float64, count=n)
        w = np.fromiter((1.0 / r[5] ** 2 for r in rows), dtype=np.float64, count=n)
        w /= cfg.correlation_samples
        Bj = (np.array([r[3] for r in rows]) - np.asarray(b0)).reshape(n, 3, 3)[np.arange(n), axes]
        Cj = (np.array([r[4] for r in rows]) - np.asarray(c0))[np.arange(n), axes]
        Lj = np.array([r[6] for r in rows])[np.arange(n), axes]
        X = np.zeros((n, N_THETA))
        X[np.arange(n), axes] = 1.0
        X[:, 3:6] = -Bj
        X[:, 6] = Cj
        X[:, LAG] = -Lj
        prior = np.array(
            [_V0_PRECISION] * 3
            + [1.0 / cfg.prior_bias_mps2**2] * 3
            + [1.0 / cfg.prior_yaw_rad**2, 1.0 / cfg.prior_lag_s**2]
        )
        present = [k for k in range(3) if np.any(axes == k)]
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
        XtW = X.T * w
        info = XtW @ X + np.diag(prior)
        rhs = XtW @ z + prior * mean
        try:
            cov = np.linalg.inv(info)
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
            sens = -c0_v @ (XtW[:3] @ X[:, 3:])
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
        nb = float(np.linalg.norm(b))
        if nb > cfg.max_bias_mps2:
            theta[3:6] = b * (cfg.max_bias_mps2 / nb)
        # a measurement is late, never early; and no autopilot is later than max_lag_s
        theta[LAG] = min(max(float(theta[LAG]), 0.0), cfg.max_lag_s)
        if not (self.frozen_bias and old is not None) and (
            (theta[LAG] - lag_prior[0]) ** 2 <= 4.0 * cov[LAG, LAG]
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


#: Time constants (s) of the low-pass a velocity step may come through: an autopilot's
#: velocity is its estimator's output, which smooths a step in the GPS velocity.
STEP_FILTER_TAUS_S = (0.0, 0.1, 0.2, 0.4)


def classify_change(
    axis: int,
    recent: list[tuple[float, int, float, tuple[float, ...]]],
    sigma_mps: tuple[float, float, float],
) -> tuple[str, tuple[float, float, float], float]:
    """Velocity step on ``axis``, accelerometer-bias step, or an offset of the reference?

    ``recent``: (t, axis, residual, B(t) flat 9) of every axis over the last
    ``change_window_s``. Three explanations of the residuals of all three axes:

    - ``"velocity"``: a step on ``axis`` alone at t_c, r_j = β (1 − e^{−(τ−t_c)/τ_f}) with
      τ_f in :data:`STEP_FILTER_TAUS_S` (a sensor bias, as the autopilot passes it on);
    - ``"accel"``: an accelerometer-bias step at t_c, r_k = −(B_k(τ) − B_k(t_c)) Δb on
      every axis: a ramp that rotates with the attitude;
    - ``"offset"``: a constant offset of ``axis`` over the whole window, no change at all
      (a reference fitted on too little data, e.g. just after a re-anchoring).

    A change must have at least ``MIN_PRE_SAMPLES`` samples of ``axis`` before it (a step
    needs a before); with fewer, ``"undecided"``. Each model is fitted for every candidate
    t_c (a sample time of ``axis``); residuals are weighted by their axis's σ_r; the lowest
    BIC wins (parameters: β, τ_f, t_c; Δb (3), t_c; the offset). Returns (kind, Δb (body,
    m/s²), t_c).
    """
    t = np.array([r[0] for r in recent])
    ax = np.array([r[1] for r in recent], dtype=np.intp)
    on_axis = ax == axis
    cand = t[on_axis][MIN_PRE_SAMPLES:-2]
    if len(cand) < 1:
        return "undecided", (0.0, 0.0, 0.0), math.nan
    res = np.array([r[2] for r in recent])
    Bf = np.array([r[3] for r in recent]).reshape(-1, 3, 3)
    s = np.asarray(sigma_mps)[ax]
    rw = res / s
    n_all = len(t)
    ln_n = math.log(n_all)

    def bic(sse: float, n_params: int) -> float:
        return n_all * math.log(max(sse, 1e-12) / n_all) + n_params * ln_n

    offset = float(np.median(res[on_axis]))
    best: tuple[float, str, tuple[float, float, float], float] = (
        bic(float(np.sum(((res - np.where(on_axis, offset, 0.0)) / s) ** 2)), 1),
        "offset",
        (0.0, 0.0, 0.0),
        float(t[on_axis][0]),
    )
    rows = np.arange(n_all)
    for tc in cand:
        after = t >= tc
        on_j = after & on_axis
        # velocity step on `axis`, through a low-pass of τ_f
        for tau in STEP_FILTER_TAUS_S:
            shape = np.where(on_j, 1.0, 0.0)
            if tau > 0.0:
                shape = shape * (1.0 - np.exp(-np.clip(t - tc, 0.0, None) / tau))
            u = shape / s
            uu = float(u @ u)
            if uu <= 0.0:
                continue
            beta = float(u @ rw) / uu
            b_v = bic(float(np.sum((rw - u * beta) ** 2)), 3 if tau > 0.0 else 2)
            if b_v < best[0]:
                best = (b_v, "velocity", (0.0, 0.0, 0.0), float(tc))
        # accelerometer step: r_k = −(B_k(τ) − B_k(t_c)) Δb for τ ≥ t_c
        Bc = Bf[int(np.searchsorted(t, tc))]
        Dw = (-(Bf - Bc)[rows, ax] * after[:, None]) / s[:, None]
        db = np.linalg.solve(Dw.T @ Dw + np.eye(3) * 1e-6, Dw.T @ rw)
        b_a = bic(float(np.sum((rw - Dw @ db) ** 2)), 4)
        if b_a < best[0]:
            best = (b_a, "accel", (float(db[0]), float(db[1]), float(db[2])), float(tc))
    return best[1], best[2], best[3]


@dataclass
class AxisMonitor:
    """FDI of one NED axis (index 0 n, 1 e, 2 d); ``fit`` is shared by the three axes."""

    axis: AxisName
    index: int
    cfg: FdiConfig
    fit: ReferenceFit
    state: AxisState = AxisState.WARMUP
    fault: FaultEvent | None = None
    sigma_r_mps: float = 0.0
    _var_r: float = 0.0
    _pending: deque[tuple[float, float, bool, Integrals, float]] = field(default_factory=deque)
    _resid: deque[float] = field(default_factory=deque)
    _last_y: float = math.nan
    _repeats: int = 0
    _nan_run: int = 0
    _fail_run: int = 0
    _healthy_since_s: float | None = None
    _t_isolated_s: float = 0.0
    _t_last_vetted_s: float | None = None
    _frozen: Reference | None = None
    _fault_level_mps: float = 0.0  # signed median residual when a bias was isolated
    _iso_resid: deque[float] = field(default_factory=lambda: deque(maxlen=24))
    _stepped_back_level: float | None = None
    _rearm_rows: int = 0
    _scale: float = 0.0  # s_j of the last test
    #: running mean of squared successive residual differences: 2 σ² of the measurement's
    #: white noise (plus the IMU's over one interval), for the gain of ``full``
    var_diff_mps2: float = 0.0
    _r_prev: float = math.nan
    #: the measurement's own second differences y_k − 2y_(k−1) + y_(k−2): their recent
    #: squares and the running mean of those squares while the axis is healthy (white noise
    #: σ gives 6σ²; smooth motion adds only jerk·Δt²)
    _y_prev: tuple[float, float] = (math.nan, math.nan)
    #: (t, r) since a residual isolation: the withdrawal rule (RAMP_LIMIT_MPS2)
    _ramp: deque[tuple[float, float]] = field(default_factory=deque)
    _d2y_sq: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    var_d2y_mps2: float = 0.0
    _v_imu_at_value: float = 0.0  # the IMU's velocity when the current value was first seen
    #: running fraction of samples that repeat the previous value exactly (healthy axis);
    #: starts at 0.5 (a prior worth 2 samples: "unknown", repeats need the IMU's word)
    _repeat_rate: float = 0.5
    _repeat_n: float = 2.0
    _rate_before_run: float = 0.5

    def __post_init__(self) -> None:
        self._var_r = self.cfg.sigma_meas_mps**2
        # white noise of σ_meas: var(y_k − 2y_(k−1) + y_(k−2)) = 6σ²
        self.var_d2y_mps2 = 6.0 * self.cfg.sigma_meas_mps**2
        self.sigma_r_mps = self.cfg.sigma_meas_mps

    # ------------------------------------------------------------------ reference
    def armed(self) -> bool:
        """Residual tests need a fit over ``warmup_s`` of vetted samples."""
        if not self.fit.imu_ok:
            return False
        return self._frozen is not None or (
            self.fit.fitted
            and self.fit.ref is not None
            and self.fit.span_s() >= self.cfg.warmup_s
            and self.index in self.fit.fitted_axes
            and self.fit.rows_per_axis[self.index] >= 10
        )

    def reference(self) -> Reference | None:
        if self._frozen is not None:
            return self._frozen
        return self.fit.ref if self.armed() else None

    def predict(
        self, a_int_j: float, ints: Integrals, *, lagged: bool = True
    ) -> tuple[float, float]:
        """(ŷ_j, σ_pred,j): the IMU's dead reckoning of this axis's measurement (``lagged``)
        or of its velocity (NaN when unarmed)."""
        ref = self.reference()
        if ref is None:
            return math.nan, math.nan
        return ref.predict(self.index, a_int_j, ints, lagged=lagged)

    def predict_mps(self, a_int_j: float, ints: Integrals, *, lagged: bool = True) -> float:
        return self.predict(a_int_j, ints, lagged=lagged)[0]

    def sigma_dead_reckoning_mps(self, t_s: float) -> float:
        """1σ of the prediction's drift, growing with the age of the newest vetted sample."""
        age = 0.0 if self._t_last_vetted_s is None else t_s - self._t_last_vetted_s
        return sigma_dead_reckoning_mps(self.cfg, age)

    def vet(self, t_s: float) -> None:
        """Move pending samples older than the vetting delay into the shared fit."""
        if self.fault is not None:
            return
        limit = t_s - self.cfg.vet_delay_s
        pend = self._pending
        while pend and pend[0][0] <= limit:
            tp, zp, clean, ints, rp = pend.popleft()
            if clean:
                self.fit.add(tp, self.index, zp, ints, self.sigma_r_mps)
                self._t_last_vetted_s = tp
                if math.isfinite(rp):
                    self._learn_scale(rp)
                if self._frozen is not None:
                    self._rearm_rows += 1
                    if self._rearm_rows >= REARM_ROWS:
                        self._frozen = None

    def _learn_scale(self, r: float) -> None:
        """σ_r: running mean of r² (winsorised at 4σ) over ~``scale_samples`` samples."""
        cap = 16.0 * self._var_r
        k = 1.0 / self.cfg.scale_samples
        self._var_r += k * (min(r * r, cap) - self._var_r)
        self.sigma_r_mps = max(self.cfg.sigma_floor_mps, math.sqrt(self._var_r))

    def rebase(self) -> None:
        """The reference was re-anchored (an accelerometer change): start the tests afresh.

        An isolation by the residual tests (bias, noise) is withdrawn: it compared the axis
        with the IMU that has just been found at fault."""
        self._resid.clear()
        self._fail_run = 0
        self._pending.clear()
        if self.fault is not None and self.fault.kind in RESIDUAL_KINDS:
            self.fault = None
            self._frozen = None
            self._healthy_since_s = None
        if self.fault is None:
            self.state = AxisState.WARMUP

    # ------------------------------------------------------------------ tests
    def bias_threshold_mps(self) -> float:
        return max(self.cfg.bias_threshold_mps, self.cfg.bias_sigma * self._scale)

    def _ratios(self) -> tuple[float, float]:
        """(bias ratio, noise ratio) of the recent residuals; NaN when too few."""
        cfg = self.cfg
        r = list(self._resid)
        rb = r[-cfg.bias_samples :]
        bias = (
            abs(statistics.median(rb)) / self.bias_threshold_mps()
            if len(rb) == cfg.bias_samples
            else math.nan
        )
        rn = r[-(cfg.noise_samples + 1) :]
        noise = math.nan
        if len(rn) == cfg.noise_samples + 1:
            d2 = [(rn[i + 1] - rn[i]) ** 2 for i in range(cfg.noise_samples)]
            nominal = 2.0 * self.sigma_r_mps**2 * CHI2_1_MEDIAN
            noise = statistics.median(d2) / nominal / cfg.noise_ratio_threshold
            # A noisy residual is a noisy measurement only if the measurement itself is
            # noisy: the IMU's path (an attitude estimator lost in a ballistic climb, a
            # vibrating accelerometer) makes the residual noisy while y stays smooth.
            own = self._own_noise_ratio()
            if math.isfinite(own):
                noise = min(noise, own)
        return bias, noise

    def _own_noise_ratio(self) -> float:
        """The measurement's own noise test: the median of its last ``noise_samples``
        squared second differences over their healthy level (NaN when too few)."""
        cfg = self.cfg
        own = list(self._d2y_sq)[-cfg.noise_samples :]
        if len(own) < cfg.noise_samples:
            return math.nan
        return (
            statistics.median(own) / (self.var_d2y_mps2 * CHI2_1_MEDIAN) / cfg.noise_ratio_threshold
        )

    def _spread_ratio(self) -> float:
        """Robust spread (1.4826 MAD) of the bias window over 3σ_r: a bias step keeps it
        small (the window holds two clusters), a noise burst makes it large."""
        rb = list(self._resid)[-self.cfg.bias_samples :]
        if len(rb) < 3:
            return 0.0
        med = statistics.median(rb)
        mad = statistics.median(abs(x - med) for x in rb)
        return 1.4826 * mad / (3.0 * self.sigma_r_mps)

    def update(self, t_s: float, y_mps: float, a_int_mps: float, ints: Integrals) -> AxisVerdict:
        """One measurement at vehicle time ``t_s``; ``a_int_mps`` = A_j(t), ``ints`` = (B, C)."""
        cfg = self.cfg
        if not math.isfinite(y_mps):
            self._nan_run += 1
            self._y_prev = (math.nan, math.nan)
            self._healthy_since_s = None
            if self._nan_run >= cfg.dropout_samples and self.state is not AxisState.FAULTY:
                self.isolate(t_s, FaultKind.DROPOUT)
            elif self.state is AxisState.RECOVERING:
                self.state = AxisState.FAULTY
            return AxisVerdict(False, math.nan, math.inf, self.state)
        self._nan_run = 0
        # freeze: exact repeats of a measurement that seldom repeats (an EKF's float output,
        # a noisy sensor), or of one that often does (a noise-free SITL GPS, a coarse step:
        # it repeats in a hover, which is a measurement, not a fault) while the IMU says
        # the velocity changed. Without a usable IMU, repeats alone count.
        pred, sigma_pred = self.predict(a_int_mps, ints)
        # the IMU's velocity (bias-corrected by the reference when there is one)
        v_imu = pred if math.isfinite(pred) else a_int_mps
        same = y_mps == self._last_y
        if not same:
            self._v_imu_at_value = v_imu
            self._rate_before_run = self._repeat_rate  # the run being judged does not count
        if self.fault is None:  # a running mean, exact over the first scale_samples
            self._repeat_n = min(self._repeat_n + 1.0, float(cfg.scale_samples))
            self._repeat_rate += (float(same) - self._repeat_rate) / self._repeat_n
        seldom = self._rate_before_run < cfg.freeze_repeat_rate
        moved = abs(v_imu - self._v_imu_at_value) > cfg.freeze_motion_mps
        repeated = same and (seldom or moved or not self.fit.imu_ok)
        self._repeats = self._repeats + 1 if repeated else 0
        self._last_y = y_mps
        r = y_mps - pred
        if math.isfinite(r):
            self._scale = math.hypot(self.sigma_r_mps, sigma_pred)
            if math.isfinite(self._r_prev) and self.state is AxisState.OK:
                d2 = (r - self._r_prev) ** 2
                if self.var_diff_mps2 == 0.0:
                    self.var_diff_mps2 = d2
                else:
                    cap = 16.0 * self.var_diff_mps2
                    self.var_diff_mps2 += (min(d2, cap) - self.var_diff_mps2) / cfg.scale_samples
            self._resid.append(r)
            while len(self._resid) > max(cfg.bias_samples, cfg.noise_samples + 1):
                self._resid.popleft()
        self._r_prev = r
        y1, y2 = self._y_prev
        if math.isfinite(y1) and math.isfinite(y2):
            d2y_sq = (y_mps - 2.0 * y1 + y2) ** 2
            self._d2y_sq.append(d2y_sq)
            if self.state is AxisState.OK:
                cap = 16.0 * self.var_d2y_mps2
                self.var_d2y_mps2 += (min(d2y_sq, cap) - self.var_d2y_mps2) / cfg.scale_samples
        self._y_prev = (y_mps, y1)
        bias_ratio, noise_ratio = self._ratios()
        freeze_ratio = self._repeats / cfg.freeze_repeats
        ratio = max(
            (x for x in (bias_ratio, noise_ratio, freeze_ratio) if math.isfinite(x)), default=0.0
        )
        if self.state in (AxisState.FAULTY, AxisState.RECOVERING):
            if math.isfinite(r) and self.fault is not None and self.fault.kind in RESIDUAL_KINDS:
                self._ramp.append((t_s, r))
                while self._ramp[0][0] < t_s - RAMP_WINDOW_S:
                    self._ramp.popleft()
            return self._recovery(
                t_s, r=r, repeated=repeated, bias_ratio=bias_ratio, noise_ratio=noise_ratio,
                ratio=ratio,
            )  # fmt: skip
        if self._repeats >= cfg.freeze_repeats:
            self.isolate(t_s, FaultKind.FREEZE)
            return AxisVerdict(False, r, ratio, self.state)
        if math.isfinite(r):
            if self.state is AxisState.WARMUP:
                self.state = AxisState.OK
            gated = abs(r) > cfg.gate_sigma * self._scale
            failing = bias_ratio > 1.0 or noise_ratio > 1.0
            if failing:
                self._fail_run += 1
                self.state = AxisState.SUSPECT
            else:
                self._fail_run = 0
                self.state = AxisState.OK
            self._pending.append((t_s, y_mps - a_int_mps, not gated and not failing, ints, r))
            return AxisVerdict(not gated and not repeated and not failing, r, ratio, self.state)
        self._pending.append((t_s, y_mps - a_int_mps, not repeated, ints, math.nan))
        return AxisVerdict(not repeated, math.nan, ratio, self.state)

    def ramping(self, t_s: float) -> bool:
        """The residual against the dead reckoning ramps faster than RAMP_LIMIT_MPS2 over
        the last RAMP_WINDOW_S of a residual isolation while the measurement itself is
        smooth: its least-squares slope beyond the limit plus 3σ of its own scatter, and a
        line fits it better than any single step (a bias that ends is a step, and
        steepens a line through it)."""
        pts = self._ramp
        if len(pts) < 8 or t_s - self._t_isolated_s < RAMP_WINDOW_S:
            return False
        # a noise fault's residual can ramp by chance over 1 s (10 samples of a filtered
        # stream): only a smooth measurement, its own second differences at their healthy
        # level, lets the ramp be the IMU's
        own = list(self._d2y_sq)[-len(pts) :]
        if own and sum(own) / len(own) > self.cfg.noise_ratio_threshold * self.var_d2y_mps2:
            return False
        t = np.fromiter((p[0] for p in pts), dtype=np.float64, count=len(pts))
        r = np.fromiter((p[1] for p in pts), dtype=np.float64, count=len(pts))
        dt = t - t.mean()
        sxx = float(dt @ dt)
        if sxx <= 0.0:
            return False
        slope = float(dt @ (r - r.mean())) / sxx
        e = r - r.mean() - slope * dt
        sse_line = float(e @ e)
        sigma_slope = math.sqrt(sse_line / (len(pts) - 2) / sxx)
        if abs(slope) <= RAMP_LIMIT_MPS2 + 3.0 * sigma_slope:
            return False
        # the best single step: two constant segments, split anywhere (≥ 2 samples each)
        c1 = np.cumsum(r)
        c2 = np.cumsum(r * r)
        n = len(r)
        k = np.arange(2, n - 1)
        left = c2[k - 1] - c1[k - 1] ** 2 / k
        right = (c2[-1] - c2[k - 1]) - (c1[-1] - c1[k - 1]) ** 2 / (n - k)
        sse_step = float(np.min(left + right))
        return sse_line < sse_step

    def wants_isolation(self) -> FaultKind | None:
        """A bias or noise test failed ``k_isolate`` samples in a row: the kind, else None."""
        if self.state is not AxisState.SUSPECT or self._fail_run < self.cfg.k_isolate:
            return None
        _, noise_ratio = self._ratios()
        if noise_ratio > 1.0 or self._spread_ratio() > 1.0:
            return FaultKind.NOISE
        return FaultKind.BIAS

    def isolate(self, t_s: float, kind: FaultKind) -> None:
        self.state = AxisState.FAULTY
        self.fault = FaultEvent(self.axis, kind.value, t_s, None)
        # dead reckoning from the fit of this moment, if it predicts this axis
        fitted = self.armed() or self.index in self.fit.fitted_axes
        self._frozen = self.fit.ref.held() if fitted and self.fit.ref is not None else None
        self.fit.frozen_bias = True
        rb = list(self._resid)[-self.cfg.bias_samples :]
        self._fault_level_mps = statistics.median(rb) if rb else 0.0
        self._iso_resid.clear()
        self._ramp.clear()
        self._stepped_back_level = None
        self._pending.clear()
        self._resid.clear()
        self._fail_run = 0
        self._healthy_since_s = None
        self._t_isolated_s = t_s

    def _recovery(
        self,
        t_s: float,
        *,
        r: float,
        repeated: bool,
        bias_ratio: float,
        noise_ratio: float,
        ratio: float,
    ) -> AxisVerdict:
        """Isolated: healthy again for ``recovery_s`` (against the dead reckoning) -> OK."""
        if self.fault is not None and self.fault.kind == FaultKind.UNAIDED.value:
            return AxisVerdict(False, r, ratio, self.state)  # the autopilot decides (set_unaided)
        slack = self.bias_threshold_mps() + 3.0 * self.sigma_dead_reckoning_mps(t_s)
        if self.fault is not None and self.fault.kind == FaultKind.BIAS.value:
            return self._bias_recovery(t_s, r=r, repeated=repeated, ratio=ratio)
        if (
            self.fault is not None
            and self.fault.kind == FaultKind.DROPOUT.value
            and (self._frozen is None)
        ):
            slack = math.inf  # nothing to compare with: values are back, that is recovery
        healthy = (
            not repeated
            and (math.isfinite(r) or math.isinf(slack))
            and (not math.isfinite(r) or abs(r) <= slack + 2.0 * self.sigma_r_mps)
            and (noise_ratio <= 1.0 or math.isinf(slack))
            and not (bias_ratio * self.bias_threshold_mps() > slack)
        )
        return self._recovery_verdict(t_s, healthy, r, ratio)

    def _bias_recovery(self, t_s: float, *, r: float, repeated: bool, ratio: float) -> AxisVerdict:
        """A bias fault ends when the measurement steps back by about the fault's size
        (a drop of more than half of it between two successive windows of
        ``bias_samples``), or comes back within a fixed level of the dead reckoning (half
        the fault, at least ``bias_threshold_mps``). The level does not grow with the dead
        reckoning's uncertainty: a persistent bias would pass a growing one. After the
        step back the level must hold (within the threshold) for ``recovery_s``."""
        cfg = self.cfg
        n = cfg.bias_samples
        beta = self._fault_level_mps
        hist = self._iso_resid
        if math.isfinite(r):
            hist.append(r)
        healthy = False
        if len(hist) >= n and not repeated and math.isfinite(r):
            now = statistics.median(list(hist)[-n:])
            if self._stepped_back_level is None and len(hist) >= 2 * n:
                before = statistics.median(list(hist)[-2 * n : -n])
                step = now - before
                if step * beta < 0.0 and abs(step) > 0.5 * abs(beta):
                    self._stepped_back_level = now
            if self._stepped_back_level is not None:
                healthy = abs(now - self._stepped_back_level) <= max(
                    cfg.bias_threshold_mps, 3.0 * self.sigma_r_mps
                )
                if not healthy:
                    self._stepped_back_level = None  # moved again: wait for a new step
            else:
                healthy = abs(now) <= max(cfg.bias_threshold_mps, 0.5 * abs(beta))
        return self._recovery_verdict(t_s, healthy, r, ratio)

    def _recovery_verdict(self, t_s: float, healthy: bool, r: float, ratio: float) -> AxisVerdict:
        """Isolated: a sample that passes the recovery test extends the healthy run; after
        ``recovery_s`` of them the axis is re-admitted. One that fails resets the run."""
        if not healthy:
            self._healthy_since_s = None
            self.state = AxisState.FAULTY
            return AxisVerdict(False, r, ratio, self.state)
        if self._healthy_since_s is None:
            self._healthy_since_s = t_s
        self.state = AxisState.RECOVERING
        if t_s - self._healthy_since_s >= self.cfg.recovery_s:
            self._readmit()
            return AxisVerdict(True, r, ratio, self.state)
        return AxisVerdict(False, r, ratio, self.state)

    def _readmit(self) -> None:
        self.state = AxisState.OK
        self.fault = None
        self._rearm_rows = 0
        rb = list(self._resid)[-self.cfg.bias_samples :]
        if self._frozen is not None and rb:
            # Re-anchor the frozen prediction on the measurement: what still separates the
            # healthy axis from the dead reckoning is the dead reckoning's drift since
            # isolation, not a sensor fault; kept, it would read as a bias step.
            self._frozen = self._frozen.shifted(self.index, statistics.median(rb))
        self._resid.clear()

    def continue_isolation(
        self, fault: FaultEvent, frozen: Reference | None, level_mps: float
    ) -> None:
        """Continue an isolation another service made (a ``serve --claim`` takeover): the
        same fault event, dead reckoning from ``frozen``, ``level_mps`` the fault's residual
        (the size a bias recovery looks for)."""
        self.isolate(fault.t_detect_s, FaultKind(fault.kind))
        self.fault = fault
        self._frozen = frozen
        self._fault_level_mps = level_mps

    def force_dropout(self, t_s: float) -> bool:
        """The measurement stream is missing: isolate as a dropout. True if newly isolated."""
        if self.state is AxisState.FAULTY:
            return False
        self.isolate(t_s, FaultKind.DROPOUT)
        return True

    def set_unaided(self, t_s: float, unaided: bool) -> None:
        """The autopilot says this axis's velocity is (not) aided (GPS lost, EKF flags)."""
        is_unaided = self.fault is not None and self.fault.kind == FaultKind.UNAIDED.value
        if unaided and not is_unaided:
            self.isolate(t_s, FaultKind.UNAIDED)
        elif not unaided and is_unaided:
            # aided again: the autopilot's estimate snaps back; restart the reference on it
            self.state = AxisState.WARMUP
            self.fault = None
            self._frozen = None
            self._resid.clear()


@dataclass(frozen=True, slots=True)
class AccelChange:
    """An accelerometer-bias change found by :func:`classify_change` (isolates no axis)."""

    t_detect_s: float
    t_change_s: float
    delta_bias_body_mps2: tuple[float, float, float]
    triggered_by: AxisName


@dataclass
class FaultDetector:
    """FDI of the three NED axes of one vehicle."""

    cfg: FdiConfig = field(default_factory=FdiConfig)
    fit: ReferenceFit = field(init=False)
    axes: tuple[AxisMonitor, AxisMonitor, AxisMonitor] = field(init=False)
    accel_changes: list[AccelChange] = field(default_factory=list)
    reference_drifts: int = 0
    #: residual isolations withdrawn on a ramping residual (RAMP_LIMIT_MPS2)
    ramp_withdrawals: int = 0
    #: (t, axis, residual, B flat 9) of every axis over the last change_window_s
    _recent: deque[tuple[float, int, float, tuple[float, ...]]] = field(default_factory=deque)

    def __post_init__(self) -> None:
        self.fit = ReferenceFit(self.cfg)
        self.axes = (
            AxisMonitor("n", 0, self.cfg, self.fit),
            AxisMonitor("e", 1, self.cfg, self.fit),
            AxisMonitor("d", 2, self.cfg, self.fit),
        )

    def update(
        self,
        t_s: float,
        y_ned_mps: tuple[float, float, float],
        a_int_mps: list[float],
        ints: Integrals,
        imu_rate_hz: float = math.inf,
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """One velocity measurement; the verdict per NED axis.

        Below ``min_imu_rate_hz`` the IMU cannot predict the velocity: the residual tests
        are off and only dropout and freeze are tested.
        """
        cfg = self.cfg
        self.fit.imu_ok = imu_rate_hz >= cfg.min_imu_rate_hz
        for ax in self.axes:
            ax.vet(t_s)
        self.fit.frozen_bias = any(ax.fault is not None for ax in self.axes)
        self.fit.prune_and_fit(t_s)
        v = (
            self.axes[0].update(t_s, y_ned_mps[0], a_int_mps[0], ints),
            self.axes[1].update(t_s, y_ned_mps[1], a_int_mps[1], ints),
            self.axes[2].update(t_s, y_ned_mps[2], a_int_mps[2], ints),
        )
        recent = self._recent
        for j, vj in enumerate(v):
            if math.isfinite(vj.residual_mps) and self.axes[j].fault is None:
                recent.append((t_s, j, vj.residual_mps, ints[0]))
        while recent and recent[0][0] < t_s - self.cfg.change_window_s:
            recent.popleft()
        return self._decide(t_s, v)

    def _decide(
        self, t_s: float, v: tuple[AxisVerdict, AxisVerdict, AxisVerdict]
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """Isolate the axes whose tests failed k times, unless an accelerometer change
        explains the residuals of all axes better (module docstring)."""
        for ax in self.axes:
            if ax.fault is not None and ax.fault.kind in RESIDUAL_KINDS and ax.ramping(t_s):
                # the IMU's path drifts, not the axis: withdraw, restart the reference
                self.ramp_withdrawals += 1
                return self._rebase(t_s, t_s, None, ax.axis, v)
        wants: list[tuple[int, FaultKind]] = []
        for j, ax in enumerate(self.axes):
            k = ax.wants_isolation()
            if k is not None:
                wants.append((j, k))
        if not wants:
            return v
        out = list(v)
        j0, k0 = wants[0]
        others = [a for a in self.axes if a.fault is not None and a.fault.kind in RESIDUAL_KINDS]
        if len(wants) >= 2 or others:
            # two velocity sensors failing at once is far less likely than one IMU or
            # attitude error seen on every axis: blame the IMU, withdraw the isolations
            _, db, t_c = classify_change(j0, list(self._recent), self._sigmas())
            return self._rebase(t_s, t_s if math.isnan(t_c) else t_c, db, self.axes[j0].axis, v)
        if k0 is FaultKind.BIAS and self.fit.ref is not None and not self.fit.frozen_bias:
            kind, db, t_c = classify_change(j0, list(self._recent), self._sigmas())
            if kind == "undecided":
                return v  # the tests fail again on the next sample, with more history
            if kind == "offset":
                self.reference_drifts += 1
                return self._rebase(t_s, t_c, None, self.axes[j0].axis, v)
            if kind == "accel":
                return self._rebase(t_s, t_c, db, self.axes[j0].axis, v)
        for j, kind_j in wants:
            self.axes[j].isolate(t_s, kind_j)
            out[j] = AxisVerdict(False, v[j].residual_mps, v[j].test_ratio, self.axes[j].state)
        return (out[0], out[1], out[2])

    def _sigmas(self) -> tuple[float, float, float]:
        return (self.axes[0].sigma_r_mps, self.axes[1].sigma_r_mps, self.axes[2].sigma_r_mps)

    def _rebase(
        self,
        t_s: float,
        t_c: float,
        db: tuple[float, float, float] | None,
        by: AxisName,
        v: tuple[AxisVerdict, AxisVerdict, AxisVerdict],
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """An accelerometer change (``db``) or a reference offset (None) at t_c: the
        reference restarts from the samples after it; no sample of this measurement is
        used (the verdicts ``v`` are returned with ``use`` off)."""
        if db is not None:
            self.accel_changes.append(AccelChange(t_s, t_c, db, by))
            self.fit.carried_prior = None  # the accelerometer changed: not its bias any more
        self.fit.drop_before(math.inf)
        for ax in self.axes:
            ax.rebase()
        self._recent.clear()
        a, b, c = (
            AxisVerdict(False, x.residual_mps, x.test_ratio, ax.state)
            for x, ax in zip(v, self.axes, strict=True)
        )
        return (a, b, c)

    def set_unaided(self, t_s: float, horizontal: bool | None, vertical: bool | None) -> None:
        """Apply the autopilot's word on what its velocity rests on (None: no word)."""
        if horizontal is not None:
            self.axes[0].set_unaided(t_s, not horizontal)
            self.axes[1].set_unaided(t_s, not horizontal)
        if vertical is not None:
            self.axes[2].set_unaided(t_s, not vertical)

    def faulty_axes(self) -> list[int]:
        """Indices (0 n, 1 e, 2 d) of the axes currently isolated, in isolation order."""
        idx = [i for i, a in enumerate(self.axes) if a.fault is not None]
        return sorted(idx, key=lambda i: self.axes[i]._t_isolated_s)

    def states(self) -> dict[str, str]:
        return {ax: m.state.value for ax, m in zip(NED_AXES, self.axes, strict=True)}

    def armed(self) -> bool:
        """Residual tests are running on every healthy axis."""
        return all(a.armed() or a.fault is not None for a in self.axes)
