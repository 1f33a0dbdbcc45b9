"""Fault detection and isolation (FDI) of the velocity sensor, one NED axis at a time.

Pure computation (no I/O): the vehicle estimator feeds it the earth-frame integral of
the IMU's acceleration and every velocity measurement; it returns, per axis, whether
the sample may be used, the residual and its test ratios, and isolation/recovery events.

The residual of axis j
----------------------
With consistent kinematics the earth-frame velocity obeys V̇ = E Γ (equations.md, "What
careful analysis adds"; Γ = f + g_body, (9)), which does not involve the body velocity.
With the accelerometer reading f = f_true + b (b a body-frame bias, constant over a few
seconds) and the integrals the vehicle keeps, A(t) = ∫ (E f + g e_d) dt and
B(t) = ∫ E dt (3×3, the same ZOH inputs as the bank):

    z(τ) = y(τ) − A(τ) = V0 − B(τ) b + n(τ)

linear in θ = (V0, b). :class:`BiasFit` solves it by least squares over the *vetted*
samples of the last ``bias_window_s`` (samples at least ``vet_delay_s`` old that passed
every test while their axis was healthy; each gives one row, for its own axis). The
body-frame b is observable from the earth-frame measurements as the vehicle turns or
from three axes at once, so a turning vehicle does not bend the prediction (an
earth-frame bias would rotate with the yaw). The predictor and residual of axis j are

    ŷ_j(t) = V0_j + A_j(t) − B_j(t) b̂,      r_j(t) = y_j(t) − ŷ_j(t)

which is what the IMU and the configuration c_j that does not use axis j predict: c_j's
lost axis is this dead reckoning. Because the reference is ``vet_delay_s`` old, a fault
isolated within that delay has not entered it, so r_j stays clean and ŷ_j is a clean
hand-over. While an axis is isolated its prediction is frozen at the fit of the moment
of isolation, and b̂ stops being refitted (the other axes keep refitting their V0).

Tests (each a named outcome, thresholds in :class:`FdiConfig`):

- dropout: ``dropout_samples`` consecutive NaN samples (a missing stream is reported by
  the vehicle as a dropout of all axes);
- freeze: ``freeze_repeats`` exact repeats of the previous value (with noise of σ 0.05
  m/s, an exact float repeat has probability ~0);
- bias: the median of the last ``bias_samples`` residuals beyond ``bias_threshold_mps``
  (the median: one outlier cannot move it);
- noise: the median of the last ``noise_samples`` squared successive differences of the
  residual over its nominal value 2σ_y²·0.4549 (0.4549 = median of χ²₁) beyond
  ``noise_ratio_threshold`` (successive differences: a bias step adds one large
  difference, a noise burst makes all of them large).

Hysteresis: bias and noise must fail ``k_isolate`` samples in a row to isolate (one
outlier does not switch); each sample whose residual is beyond ``gate_sigma`` σ is kept
out of the full observer (gated) while the tests decide. Recovery: the axis must pass
every test (residual against the dead-reckoned prediction within the bias threshold
plus 3σ of the dead-reckoning uncertainty) for ``recovery_s`` without a break.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from glmav_observer.records import NED_AXES, AxisName, FaultEvent

#: Vetted samples of a recovered axis before its prediction comes from the live fit again
#: (> the 6 rows between two fits, and enough to pin its V0: 20 samples = 0.67 s at 30 Hz).
REARM_ROWS = 20
#: Median of the χ² distribution with one degree of freedom.
CHI2_1_MEDIAN = 0.45494


class AxisState(Enum):
    """Health of one velocity axis (HealthRecord ``axis_state``)."""

    WARMUP = "warmup"  # no vetted reference yet: only dropout and freeze are tested
    OK = "ok"
    SUSPECT = "suspect"  # a test fails, not yet k samples in a row
    FAULTY = "faulty"  # isolated
    RECOVERING = "recovering"  # isolated, healthy again for less than recovery_s


class FaultKind(Enum):
    DROPOUT = "dropout"
    FREEZE = "freeze"
    BIAS = "bias"
    NOISE = "noise"


@dataclass(frozen=True, slots=True)
class FdiConfig:
    """FDI settings (``[fdi]`` of ``configs/service.toml``; all documented there)."""

    sigma_meas_mps: float = 0.05
    vet_delay_s: float = 0.6
    bias_window_s: float = 4.0
    warmup_s: float = 1.5
    gate_sigma: float = 3.0
    dropout_samples: int = 2
    missing_timeout_s: float = 0.3
    freeze_repeats: int = 3
    bias_samples: int = 6
    bias_threshold_mps: float = 0.18
    noise_samples: int = 12
    noise_ratio_threshold: float = 12.0
    k_isolate: int = 3
    recovery_s: float = 2.0
    sigma_handover_mps: float = 0.03
    sigma_bias_mps2: float = 0.03
    accel_noise_density: float = 4e-3
    min_imu_rate_hz: float = 50.0


@dataclass(frozen=True, slots=True)
class AxisVerdict:
    """What the FDI says about one axis after one measurement."""

    use: bool  # feed this sample to the observers that measure the axis
    residual_mps: float  # NaN if not computable
    test_ratio: float  # max over the tests of statistic/threshold; > 1 fails
    state: AxisState


@dataclass
class BiasFit:
    """Least squares of z = V0 − B b over vetted rows (module docstring), shared by the axes."""

    cfg: FdiConfig
    #: rows (t, axis, z_j, B(t) flat 9): one per vetted sample
    rows: deque[tuple[float, int, float, tuple[float, ...]]] = field(default_factory=deque)
    v0_mps: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    bias_body_mps2: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    b_anchor: tuple[float, ...] = (0.0,) * 9
    fitted: bool = False
    frozen_bias: bool = False
    #: the IMU is fast enough to predict the velocity (``min_imu_rate_hz``)
    imu_ok: bool = True
    _since_fit: int = 0
    #: vetted rows per axis in the window (an axis needs its own rows to be predicted)
    rows_per_axis: list[int] = field(default_factory=lambda: [0, 0, 0])
    #: axes whose V0 the last fit determined
    fitted_axes: frozenset[int] = frozenset()

    def add(self, t_s: float, axis: int, z_mps: float, b_int: tuple[float, ...]) -> None:
        self.rows.append((t_s, axis, z_mps, b_int))
        self.rows_per_axis[axis] += 1
        self._since_fit += 1

    def prune_and_fit(self, t_s: float) -> None:
        t_min = t_s - self.cfg.vet_delay_s - self.cfg.bias_window_s
        rows = self.rows
        while rows and rows[0][0] < t_min:
            self.rows_per_axis[rows.popleft()[1]] -= 1
        if self._since_fit >= 15 or (not self.fitted and self._since_fit > 0):
            self._since_fit = 0
            self._fit()

    def span_s(self) -> float:
        return self.rows[-1][0] - self.rows[0][0] if self.rows else 0.0

    def _fit(self) -> None:
        rows = self.rows
        if len(rows) < 12 or self.span_s() < 1.0:
            return
        b0 = rows[0][3]
        n = len(rows)
        axes = np.fromiter((r[1] for r in rows), dtype=np.intp, count=n)
        z = np.fromiter((r[2] for r in rows), dtype=np.float64, count=n)
        Bfull = np.array([r[3] for r in rows]) - np.asarray(b0)  # (n, 9) B(τ) − B(τ0)
        Bj = Bfull.reshape(n, 3, 3)[np.arange(n), axes]  # row j of B for each sample
        present = [k for k in range(3) if np.any(axes == k)]
        if self.frozen_bias or len(present) < 3:
            # b held: V0_j = mean of z_j + B_j b over the window, per axis present
            b = np.asarray(self.bias_body_mps2)
            zc = z + Bj @ b
            for k in present:
                self.v0_mps[k] = float(zc[axes == k].mean())
            self.b_anchor = tuple(b0)
            self.fitted_axes = frozenset(present)
            return
        X = np.zeros((n, 6))
        X[np.arange(n), axes] = 1.0
        X[:, 3:] = -Bj
        theta, *_ = np.linalg.lstsq(X, z, rcond=None)
        self.v0_mps = theta[:3].tolist()
        self.bias_body_mps2 = theta[3:].tolist()
        self.b_anchor = tuple(b0)
        self.fitted = True
        self.fitted_axes = frozenset(present)

    def params(self, axis: int) -> tuple[float, tuple[float, float, float], tuple[float, ...]]:
        """(V0_j, b̂, B anchor) for predictions of axis ``axis``."""
        b = self.bias_body_mps2
        return self.v0_mps[axis], (b[0], b[1], b[2]), self.b_anchor


def _predict(
    params: tuple[float, tuple[float, float, float], tuple[float, ...]],
    axis: int,
    a_int_j: float,
    b_int: tuple[float, ...],
) -> float:
    v0, b, b0 = params
    k = 3 * axis
    return (
        v0
        + a_int_j
        - (b_int[k] - b0[k]) * b[0]
        - (b_int[k + 1] - b0[k + 1]) * b[1]
        - (b_int[k + 2] - b0[k + 2]) * b[2]
    )


@dataclass
class AxisMonitor:
    """FDI of one NED axis (index 0 n, 1 e, 2 d); ``fit`` is shared by the three axes."""

    axis: AxisName
    index: int
    cfg: FdiConfig
    fit: BiasFit
    state: AxisState = AxisState.WARMUP
    fault: FaultEvent | None = None
    _pending: deque[tuple[float, float, bool, tuple[float, ...]]] = field(default_factory=deque)
    _resid: deque[float] = field(default_factory=deque)
    _last_y: float = math.nan
    _repeats: int = 0
    _nan_run: int = 0
    _fail_run: int = 0
    _healthy_since_s: float | None = None
    _t_isolated_s: float = 0.0
    _t_last_vetted_s: float | None = None
    _frozen: tuple[float, tuple[float, float, float], tuple[float, ...]] | None = None
    _fault_level_mps: float = 0.0  # |median residual| when a bias fault was isolated
    _rearm_rows: int = 0

    # ------------------------------------------------------------------ reference
    def armed(self) -> bool:
        """Residual tests need a fit over ``warmup_s`` of vetted samples."""
        if not self.fit.imu_ok:
            return False
        return self._frozen is not None or (
            self.fit.fitted
            and self.fit.span_s() >= self.cfg.warmup_s
            and self.index in self.fit.fitted_axes
            and self.fit.rows_per_axis[self.index] >= 10
        )

    def predict_mps(self, a_int_j: float, b_int: tuple[float, ...]) -> float:
        """ŷ_j(t): the dead-reckoned velocity of this axis from the vetted fit (NaN unarmed)."""
        if self._frozen is not None:
            return _predict(self._frozen, self.index, a_int_j, b_int)
        if not self.armed():
            return math.nan
        return _predict(self.fit.params(self.index), self.index, a_int_j, b_int)

    def sigma_dead_reckoning_mps(self, t_s: float) -> float:
        """1σ of the prediction, growing with the age of the newest vetted sample."""
        age = 0.0 if self._t_last_vetted_s is None else max(0.0, t_s - self._t_last_vetted_s)
        c = self.cfg
        return math.sqrt(
            c.sigma_handover_mps**2
            + (c.sigma_bias_mps2 * age) ** 2
            + c.accel_noise_density**2 * age
        )

    def vet(self, t_s: float) -> None:
        """Move pending samples older than the vetting delay into the shared fit.

        After a recovery the frozen prediction is kept until ``REARM_ROWS`` new samples of
        this axis are in the fit (the fit has then been refreshed with them).
        """
        if self.fault is not None:
            return
        limit = t_s - self.cfg.vet_delay_s
        pend = self._pending
        while pend and pend[0][0] <= limit:
            tp, zp, clean, bp = pend.popleft()
            if clean:
                self.fit.add(tp, self.index, zp, bp)
                self._t_last_vetted_s = tp
                if self._frozen is not None:
                    self._rearm_rows += 1
                    if self._rearm_rows >= REARM_ROWS:
                        self._frozen = None

    # ------------------------------------------------------------------ tests
    def _ratios(self) -> tuple[float, float]:
        """(bias ratio, noise ratio) of the recent residuals; NaN when too few."""
        cfg = self.cfg
        r = list(self._resid)
        rb = r[-cfg.bias_samples :]
        bias = (
            abs(statistics.median(rb)) / cfg.bias_threshold_mps
            if len(rb) == cfg.bias_samples
            else math.nan
        )
        rn = r[-(cfg.noise_samples + 1) :]
        noise = math.nan
        if len(rn) == cfg.noise_samples + 1:
            d2 = [(rn[i + 1] - rn[i]) ** 2 for i in range(cfg.noise_samples)]
            nominal = 2.0 * cfg.sigma_meas_mps**2 * CHI2_1_MEDIAN
            noise = statistics.median(d2) / nominal / cfg.noise_ratio_threshold
        return bias, noise

    def _spread_ratio(self) -> float:
        """Robust spread (1.4826 MAD) of the bias window over 3σ_y: a bias step keeps it
        small (the window holds two clusters), a noise burst makes it large."""
        rb = list(self._resid)[-self.cfg.bias_samples :]
        if len(rb) < 3:
            return 0.0
        med = statistics.median(rb)
        mad = statistics.median(abs(x - med) for x in rb)
        return 1.4826 * mad / (3.0 * self.cfg.sigma_meas_mps)

    def update(
        self, t_s: float, y_mps: float, a_int_mps: float, b_int: tuple[float, ...]
    ) -> AxisVerdict:
        """One measurement at vehicle time ``t_s``; ``a_int_mps`` = A_j(t), ``b_int`` = B(t)."""
        cfg = self.cfg
        # dropout
        if not math.isfinite(y_mps):
            self._nan_run += 1
            self._healthy_since_s = None
            if self._nan_run >= cfg.dropout_samples and self.state is not AxisState.FAULTY:
                self._isolate(t_s, FaultKind.DROPOUT, onset_s=None)
            elif self.state is AxisState.RECOVERING:
                self.state = AxisState.FAULTY
            return AxisVerdict(False, math.nan, math.inf, self.state)
        self._nan_run = 0
        # freeze: exact repeats of the previous value
        repeated = y_mps == self._last_y
        self._repeats = self._repeats + 1 if repeated else 0
        self._last_y = y_mps
        pred = self.predict_mps(a_int_mps, b_int)
        r = y_mps - pred
        if math.isfinite(r):
            self._resid.append(r)
            while len(self._resid) > max(cfg.bias_samples, cfg.noise_samples + 1):
                self._resid.popleft()
        bias_ratio, noise_ratio = self._ratios()
        freeze_ratio = self._repeats / cfg.freeze_repeats
        ratio = max(
            (x for x in (bias_ratio, noise_ratio, freeze_ratio) if math.isfinite(x)), default=0.0
        )
        if self.state in (AxisState.FAULTY, AxisState.RECOVERING):
            return self._recovery(
                t_s,
                r=r,
                repeated=repeated,
                bias_ratio=bias_ratio,
                noise_ratio=noise_ratio,
                ratio=ratio,
            )
        if self._repeats >= cfg.freeze_repeats:
            self._isolate(t_s, FaultKind.FREEZE, onset_s=None)
            return AxisVerdict(False, r, ratio, self.state)
        if math.isfinite(r):
            if self.state is AxisState.WARMUP:
                self.state = AxisState.OK
            sigma_r = math.hypot(cfg.sigma_meas_mps, self.sigma_dead_reckoning_mps(t_s))
            gated = abs(r) > cfg.gate_sigma * sigma_r
            failing = bias_ratio > 1.0 or noise_ratio > 1.0
            if failing:
                kind = (
                    FaultKind.NOISE
                    if noise_ratio > 1.0 or self._spread_ratio() > 1.0
                    else (FaultKind.BIAS)
                )
                self._fail_run += 1
                self.state = AxisState.SUSPECT
                if self._fail_run >= cfg.k_isolate:
                    self._isolate(t_s, kind, onset_s=None)
                    return AxisVerdict(False, r, ratio, self.state)
            else:
                self._fail_run = 0
                self.state = AxisState.OK
            self._pending.append((t_s, y_mps - a_int_mps, not gated and not failing, b_int))
            return AxisVerdict(not gated and not repeated, r, ratio, self.state)
        # warm-up: no reference yet
        self._pending.append((t_s, y_mps - a_int_mps, not repeated, b_int))
        return AxisVerdict(not repeated, math.nan, ratio, self.state)

    def _isolate(self, t_s: float, kind: FaultKind, onset_s: float | None) -> None:
        self.state = AxisState.FAULTY
        self.fault = FaultEvent(self.axis, kind.value, t_s, onset_s)
        # freeze the prediction: dead reckoning from the vetted fit of this moment
        self._frozen = self.fit.params(self.index) if self.armed() else None
        self.fit.frozen_bias = True
        rb = list(self._resid)[-self.cfg.bias_samples :]
        self._fault_level_mps = abs(statistics.median(rb)) if rb else 0.0
        self._pending.clear()  # samples since the onset never enter the reference
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
        cfg = self.cfg
        slack = cfg.bias_threshold_mps + 3.0 * self.sigma_dead_reckoning_mps(t_s)
        if self.fault is not None and self.fault.kind == FaultKind.BIAS.value:
            # a persistent bias would pass a slack that grows with the dead reckoning: the
            # median residual must come back below a fixed level (half the fault's size)
            slack = max(cfg.bias_threshold_mps, 0.5 * self._fault_level_mps)
        healthy = (
            not repeated
            and math.isfinite(r)
            and abs(r) <= slack + 2.0 * cfg.sigma_meas_mps
            and noise_ratio <= 1.0  # NaN (too few samples yet) is not healthy
            and not (bias_ratio * cfg.bias_threshold_mps > slack)
        )
        if not healthy:
            self._healthy_since_s = None
            self.state = AxisState.FAULTY
            return AxisVerdict(False, r, ratio, self.state)
        if self._healthy_since_s is None:
            self._healthy_since_s = t_s
        self.state = AxisState.RECOVERING
        if t_s - self._healthy_since_s >= cfg.recovery_s:
            self.state = AxisState.OK
            self.fault = None
            self._rearm_rows = 0  # the frozen prediction is kept until the fit is refreshed
            rb = list(self._resid)[-cfg.bias_samples :]
            if self._frozen is not None and rb:
                # Re-anchor the frozen prediction on the measurement: the axis has passed
                # every test for recovery_s, so what still separates it from the dead
                # reckoning is the dead reckoning's drift since isolation (grown with the
                # residual accelerometer bias), not a sensor fault. Kept as it was, that
                # drift would read as a bias step and isolate the axis again.
                v0, b, anchor = self._frozen
                self._frozen = (v0 + statistics.median(rb), b, anchor)
            self._resid.clear()
            return AxisVerdict(True, r, ratio, self.state)
        return AxisVerdict(False, r, ratio, self.state)

    def predict_for_handover(self, a_int_mps: float, b_int: tuple[float, ...]) -> float:
        return self.predict_mps(a_int_mps, b_int)

    def force_dropout(self, t_s: float) -> bool:
        """The measurement stream is missing: isolate as a dropout. True if newly isolated."""
        if self.state is AxisState.FAULTY:
            return False
        self._isolate(t_s, FaultKind.DROPOUT, onset_s=None)
        return True


@dataclass
class FaultDetector:
    """FDI of the three NED axes of one vehicle."""

    cfg: FdiConfig = field(default_factory=FdiConfig)
    fit: BiasFit = field(init=False)
    axes: tuple[AxisMonitor, AxisMonitor, AxisMonitor] = field(init=False)

    def __post_init__(self) -> None:
        self.fit = BiasFit(self.cfg)
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
        b_int: tuple[float, ...],
        imu_rate_hz: float = math.inf,
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """One velocity measurement; the verdict per NED axis.

        Below ``min_imu_rate_hz`` the IMU cannot predict the velocity (a ZOH of the
        specific force over > 20 ms misses the vehicle's accelerations): the residual
        tests are off and only dropout and freeze are tested.
        """
        self.fit.imu_ok = imu_rate_hz >= self.cfg.min_imu_rate_hz
        for ax in self.axes:
            ax.vet(t_s)
        self.fit.frozen_bias = any(ax.fault is not None for ax in self.axes)
        self.fit.prune_and_fit(t_s)
        return (
            self.axes[0].update(t_s, y_ned_mps[0], a_int_mps[0], b_int),
            self.axes[1].update(t_s, y_ned_mps[1], a_int_mps[1], b_int),
            self.axes[2].update(t_s, y_ned_mps[2], a_int_mps[2], b_int),
        )

    def faulty_axes(self) -> list[int]:
        """Indices (0 n, 1 e, 2 d) of the axes currently isolated, in isolation order."""
        idx = [i for i, a in enumerate(self.axes) if a.fault is not None]
        return sorted(idx, key=lambda i: self.axes[i]._t_isolated_s)

    def bias_body_mps2(self) -> list[float]:
        """b̂: the body-frame (FRD) accelerometer bias estimate (m/s²), zero before the fit."""
        return list(self.fit.bias_body_mps2)

    def states(self) -> dict[str, str]:
        return {ax: m.state.value for ax, m in zip(NED_AXES, self.axes, strict=True)}
