"""The FDI of one NED axis (:class:`AxisMonitor`): the measurement against the shared
reference, its tests, isolation and recovery.

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

Hysteresis: bias and noise must fail ``k_isolate`` samples in a row; a sample beyond
``gate_sigma`` · s_j is kept out of ``full`` meanwhile. Recovery: the axis must pass every
test against the frozen dead reckoning for ``recovery_s``.

A residual isolation is withdrawn when the residual against the dead reckoning ramps
faster than ``ramp_limit_mps2`` (beyond 3σ of the slope) over the last ``ramp_window_s``
(:meth:`AxisMonitor.ramping`). The inner constants are :class:`FdiTuning`'s
(``cfg.tuning``), each with its reason.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from glmav_observer.estimation.fdi_kernels import residual_ratios
from glmav_observer.estimation.fdi_reference import (
    Integrals,
    Reference,
    ReferenceFit,
    sigma_dead_reckoning_mps,
)
from glmav_observer.estimation.fdi_types import (
    RESIDUAL_KINDS,
    AxisState,
    AxisVerdict,
    FaultKind,
    FdiConfig,
)
from glmav_observer.records import AxisName, FaultEvent

#: The states as module constants: in Python 3.11 an Enum member read as a class attribute
#: (``AxisState.OK``) takes the slow path of EnumType.__getattr__ (~0.2 µs), and one
#: measurement's tests read ~25 of them.
WARMUP, OK, SUSPECT, FAULTY, RECOVERING = (
    AxisState.WARMUP,
    AxisState.OK,
    AxisState.SUSPECT,
    AxisState.FAULTY,
    AxisState.RECOVERING,
)

#: Median of the χ² distribution with one degree of freedom.
CHI2_1_MEDIAN = 0.45494


@dataclass
class AxisMonitor:
    """FDI of one NED axis (index 0 n, 1 e, 2 d); ``fit`` is shared by the three axes."""

    axis: AxisName
    index: int
    cfg: FdiConfig
    fit: ReferenceFit
    state: AxisState = WARMUP
    fault: FaultEvent | None = None
    sigma_r_mps: float = 0.0
    _var_r: float = 0.0
    _pending: deque[tuple[float, float, bool, Integrals, float]] = field(default_factory=deque)
    #: the last max(bias_samples, noise_samples + 1) residuals (the tests' windows)
    _resid: deque[float] = field(init=False)
    _last_y: float = math.nan
    _repeats: int = 0
    _nan_run: int = 0
    _fail_run: int = 0
    _healthy_since_s: float | None = None
    _t_isolated_s: float = 0.0
    _t_last_vetted_s: float | None = None
    _frozen: Reference | None = None
    _fault_level_mps: float = 0.0  # signed median residual when a bias was isolated
    _iso_resid: deque[float] = field(init=False)
    _stepped_back_level: float | None = None
    _rearm_rows: int = 0
    _scale: float = 0.0  # s_j of the last test
    #: running mean of squared successive residual differences: 2 σ² of the measurement's
    #: white noise (plus the IMU's over one interval), for the gain of ``full``; exact over
    #: its first ``scale_samples`` (``n_diff`` of them so far), then a running mean
    var_diff_mps2: float = 0.0
    n_diff: int = 0
    _r_prev: float = math.nan
    #: the measurement's own second differences y_k − 2y_(k−1) + y_(k−2): their recent
    #: squares and the running mean of those squares while the axis is healthy (white noise
    #: σ gives 6σ²; smooth motion adds only jerk·Δt²)
    _y_prev: tuple[float, float] = (math.nan, math.nan)
    #: (t, r) since a residual isolation: the withdrawal rule (``ramp_limit_mps2``)
    _ramp: deque[tuple[float, float]] = field(default_factory=deque)
    _d2y_sq: deque[float] = field(init=False)
    var_d2y_mps2: float = 0.0
    _v_imu_at_value: float = 0.0  # the IMU's velocity when the current value was first seen
    #: running fraction of samples that repeat the previous value exactly (healthy axis);
    #: starts at ``freeze_prior_rate`` (a prior worth ``freeze_prior_samples``: "unknown",
    #: repeats need the IMU's word)
    _repeat_rate: float = field(init=False)
    _repeat_n: float = field(init=False)
    _rate_before_run: float = field(init=False)
    #: the winsorising cap of the running means, in their current value (``scale_winsor_sigma``²)
    _winsor_sq: float = field(init=False)

    def __post_init__(self) -> None:
        t = self.cfg.tuning
        self._iso_resid = deque(maxlen=t.bias_recovery_history)
        self._d2y_sq = deque(maxlen=t.own_noise_history)
        self._repeat_rate = self._rate_before_run = t.freeze_prior_rate
        self._repeat_n = t.freeze_prior_samples
        self._winsor_sq = t.scale_winsor_sigma**2
        self._resid = deque(maxlen=max(self.cfg.bias_samples, self.cfg.noise_samples + 1))
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
            and self.fit.rows_per_axis[self.index] >= self.cfg.tuning.arm_min_rows
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
                    if self._rearm_rows >= self.cfg.tuning.rearm_rows:
                        self._frozen = None

    def _learn_scale(self, r: float) -> None:
        """σ_r: running mean of r² (winsorised at ``scale_winsor_sigma``) over
        ~``scale_samples`` samples."""
        cap = self._winsor_sq * self._var_r
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
            self.state = WARMUP

    # ------------------------------------------------------------------ tests
    def bias_threshold_mps(self) -> float:
        return max(self.cfg.bias_threshold_mps, self.cfg.bias_sigma * self._scale)

    def _ratios(self) -> tuple[float, float]:
        """(bias ratio, noise ratio) of the recent residuals; NaN when too few.

        Bias: |median of the last ``bias_samples`` residuals| over the bias threshold.
        Noise: the median of the last ``noise_samples`` squared successive differences
        over their nominal 2σ_r²·0.4549; a noisy residual is a noisy measurement only if
        the measurement itself is noisy (the IMU's path, an attitude estimator lost in a
        ballistic climb or a vibrating accelerometer, makes the residual noisy while y
        stays smooth), so the lower of that and the measurement's own noise ratio (its
        last ``noise_samples`` squared second differences over their healthy level).
        The medians are compiled (:func:`.fdi_kernels.residual_ratios`)."""
        cfg = self.cfg
        return residual_ratios(
            self._resid, self._d2y_sq, cfg.bias_samples, cfg.noise_samples,
            self.bias_threshold_mps(), self.sigma_r_mps, self.var_d2y_mps2,
            cfg.noise_ratio_threshold, CHI2_1_MEDIAN,
        )  # fmt: skip

    def _spread_ratio(self) -> float:
        """Robust spread (1.4826 MAD) of the bias window over ``noise_spread_sigma`` σ_r: a
        bias step keeps it small (the window holds two clusters), a noise burst makes it
        large."""
        rb = list(self._resid)[-self.cfg.bias_samples :]
        if len(rb) < 3:
            return 0.0
        med = statistics.median(rb)
        mad = statistics.median(abs(x - med) for x in rb)
        return 1.4826 * mad / (self.cfg.tuning.noise_spread_sigma * self.sigma_r_mps)

    def update(self, t_s: float, y_mps: float, a_int_mps: float, ints: Integrals) -> AxisVerdict:
        """One measurement at vehicle time ``t_s``; ``a_int_mps`` = A_j(t), ``ints`` = (B, C)."""
        cfg = self.cfg
        if not math.isfinite(y_mps):
            self._nan_run += 1
            self._y_prev = (math.nan, math.nan)
            self._healthy_since_s = None
            if self._nan_run >= cfg.dropout_samples and self.state is not FAULTY:
                self.isolate(t_s, FaultKind.DROPOUT)
            elif self.state is RECOVERING:
                self.state = FAULTY
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
            if math.isfinite(self._r_prev) and self.state is OK:
                d2 = (r - self._r_prev) ** 2
                self.n_diff += 1
                if self.n_diff <= cfg.scale_samples:
                    # the exact mean of the first ones: winsorised against an estimate
                    # of a few samples (one χ²₁ draw can be 1e-3 of its mean) it would
                    # grow by at most 6 % a sample and understate the noise for ~400
                    # samples; unwinsorised, an outlier can only overstate it (a lower γ)
                    self.var_diff_mps2 += (d2 - self.var_diff_mps2) / self.n_diff
                else:
                    cap = self._winsor_sq * self.var_diff_mps2
                    self.var_diff_mps2 += (min(d2, cap) - self.var_diff_mps2) / cfg.scale_samples
            self._resid.append(r)
        self._r_prev = r
        y1, y2 = self._y_prev
        if math.isfinite(y1) and math.isfinite(y2):
            d2y_sq = (y_mps - 2.0 * y1 + y2) ** 2
            self._d2y_sq.append(d2y_sq)
            if self.state is OK:
                cap = self._winsor_sq * self.var_d2y_mps2
                self.var_d2y_mps2 += (min(d2y_sq, cap) - self.var_d2y_mps2) / cfg.scale_samples
        self._y_prev = (y_mps, y1)
        bias_ratio, noise_ratio = self._ratios()
        # the largest of the finite ratios (freeze's always is)
        ratio = self._repeats / cfg.freeze_repeats
        if bias_ratio > ratio and math.isfinite(bias_ratio):
            ratio = bias_ratio
        if noise_ratio > ratio and math.isfinite(noise_ratio):
            ratio = noise_ratio
        if self.state in (FAULTY, RECOVERING):
            if math.isfinite(r) and self.fault is not None and self.fault.kind in RESIDUAL_KINDS:
                self._ramp.append((t_s, r))
                while self._ramp[0][0] < t_s - cfg.tuning.ramp_window_s:
                    self._ramp.popleft()
            return self._recovery(
                t_s, r=r, repeated=repeated, bias_ratio=bias_ratio, noise_ratio=noise_ratio,
                ratio=ratio,
            )  # fmt: skip
        if self._repeats >= cfg.freeze_repeats:
            self.isolate(t_s, FaultKind.FREEZE)
            return AxisVerdict(False, r, ratio, self.state)
        if math.isfinite(r):
            if self.state is WARMUP:
                self.state = OK
            gated = abs(r) > cfg.gate_sigma * self._scale
            failing = bias_ratio > 1.0 or noise_ratio > 1.0
            if failing:
                self._fail_run += 1
                self.state = SUSPECT
            else:
                self._fail_run = 0
                self.state = OK
            self._pending.append((t_s, y_mps - a_int_mps, not gated and not failing, ints, r))
            return AxisVerdict(not gated and not repeated and not failing, r, ratio, self.state)
        self._pending.append((t_s, y_mps - a_int_mps, not repeated, ints, math.nan))
        return AxisVerdict(not repeated, math.nan, ratio, self.state)

    def ramping(self, t_s: float) -> bool:
        """The residual against the dead reckoning ramps faster than ``ramp_limit_mps2`` over
        the last ``ramp_window_s`` of a residual isolation while the measurement itself is
        smooth: its least-squares slope beyond the limit plus ``ramp_slope_sigma`` σ of its
        own scatter, and a
        line fits it better than any single step (a bias that ends is a step, and
        steepens a line through it)."""
        pts = self._ramp
        tun = self.cfg.tuning
        if len(pts) < tun.ramp_min_samples or t_s - self._t_isolated_s < tun.ramp_window_s:
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
        if abs(slope) <= tun.ramp_limit_mps2 + tun.ramp_slope_sigma * sigma_slope:
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
        if self.state is not SUSPECT or self._fail_run < self.cfg.k_isolate:
            return None
        _, noise_ratio = self._ratios()
        if noise_ratio > 1.0 or self._spread_ratio() > 1.0:
            return FaultKind.NOISE
        return FaultKind.BIAS

    def isolate(self, t_s: float, kind: FaultKind) -> None:
        self.state = FAULTY
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
        tun = self.cfg.tuning
        slack = self.bias_threshold_mps() + tun.recovery_dr_sigma * self.sigma_dead_reckoning_mps(
            t_s
        )
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
            and (
                not math.isfinite(r) or abs(r) <= slack + tun.recovery_meas_sigma * self.sigma_r_mps
            )
            and (noise_ratio <= 1.0 or math.isinf(slack))
            and not (bias_ratio * self.bias_threshold_mps() > slack)
        )
        return self._recovery_verdict(t_s, healthy, r, ratio)

    def _bias_recovery(self, t_s: float, *, r: float, repeated: bool, ratio: float) -> AxisVerdict:
        """A bias fault ends when the measurement steps back by about the fault's size
        (a drop of more than ``bias_step_back_fraction`` of it between two successive
        windows of ``bias_samples``), or comes back within a fixed level of the dead
        reckoning (``bias_return_fraction`` of the fault, at least ``bias_threshold_mps``). The level does not grow with the dead
        reckoning's uncertainty: a persistent bias would pass a growing one. After the
        step back the level must hold (within the threshold) for ``recovery_s``."""
        cfg = self.cfg
        tun = cfg.tuning
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
                if step * beta < 0.0 and abs(step) > tun.bias_step_back_fraction * abs(beta):
                    self._stepped_back_level = now
            if self._stepped_back_level is not None:
                healthy = abs(now - self._stepped_back_level) <= max(
                    cfg.bias_threshold_mps, tun.bias_hold_sigma * self.sigma_r_mps
                )
                if not healthy:
                    self._stepped_back_level = None  # moved again: wait for a new step
            else:
                healthy = abs(now) <= max(
                    cfg.bias_threshold_mps, tun.bias_return_fraction * abs(beta)
                )
        return self._recovery_verdict(t_s, healthy, r, ratio)

    def _recovery_verdict(self, t_s: float, healthy: bool, r: float, ratio: float) -> AxisVerdict:
        """Isolated: a sample that passes the recovery test extends the healthy run; after
        ``recovery_s`` of them the axis is re-admitted. One that fails resets the run."""
        if not healthy:
            self._healthy_since_s = None
            self.state = FAULTY
            return AxisVerdict(False, r, ratio, self.state)
        if self._healthy_since_s is None:
            self._healthy_since_s = t_s
        self.state = RECOVERING
        if t_s - self._healthy_since_s >= self.cfg.recovery_s:
            self._readmit()
            return AxisVerdict(True, r, ratio, self.state)
        return AxisVerdict(False, r, ratio, self.state)

    def _readmit(self) -> None:
        self.state = OK
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
        if self.state is FAULTY:
            return False
        self.isolate(t_s, FaultKind.DROPOUT)
        return True

    def restart_reference(self) -> None:
        """The autopilot's velocity is aided again after a stretch unaided: its estimate
        snaps back to the aiding sensor, so the axis warms up again on the new level
        (``drift.DriftAxes``; no isolation is involved)."""
        self.state = WARMUP
        if self.fault is not None and self.fault.kind == FaultKind.UNAIDED.value:
            self.fault = None  # (a seed from an older version may carry one)
        self._frozen = None
        self._resid.clear()
