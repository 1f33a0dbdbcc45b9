"""Fault detection and isolation (FDI) of the velocity sensor, one NED axis at a time.

Pure computation (no I/O): the vehicle estimator feeds it the earth-frame integral of
the IMU's acceleration and every velocity measurement; it returns, per axis, whether
the sample may be used, the residual and its test ratios, and isolation/recovery events.

The residual of axis j
----------------------
With consistent kinematics the earth-frame velocity obeys V̇ = E Γ (equations.md, "What
careful analysis adds"; Γ = f + g_body, (9)), which does not involve the body velocity.
So with A(t) = ∫ (E f + g e_d) dt (the IMU's earth-frame acceleration integrated, the
same ZOH inputs as the bank),

    z_j(τ) = y_j(τ) − A_j(τ) = V_j(0) − b_j τ + n_j(τ)

is constant up to the earth-frame accelerometer bias b_j (a slope) and the measurement
noise n_j. The predictor of y_j at t is built from *vetted* samples only, i.e. samples
at least ``vet_delay_s`` old that passed every test while the axis was healthy:

    ŷ_j(t) = z̄_j + A_j(t) − b̂_j (t − τ̄_j),      r_j(t) = y_j(t) − ŷ_j(t)

z̄_j, τ̄_j the mean over the last ``reference_window_s`` of vetted samples and b̂_j the
least-squares slope of z_j over the last ``bias_window_s`` of vetted samples. The
predictor is what the IMU and the configuration c_j that does not use axis j predict:
c_j's lost axis is exactly this dead reckoning (a hand-over from the vetted estimate).
Because the reference is ``vet_delay_s`` old, a fault isolated within that delay has
not entered it, so r_j stays a clean residual and the predictor a clean hand-over.

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

from glmav_observer.records import NED_AXES, AxisName, FaultEvent

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
    reference_window_s: float = 0.3
    bias_window_s: float = 4.0
    warmup_s: float = 1.5
    gate_sigma: float = 3.0
    dropout_samples: int = 2
    missing_timeout_s: float = 0.3
    freeze_repeats: int = 3
    bias_samples: int = 6
    bias_threshold_mps: float = 0.15
    noise_samples: int = 12
    noise_ratio_threshold: float = 8.0
    k_isolate: int = 3
    recovery_s: float = 2.0
    sigma_handover_mps: float = 0.03
    sigma_bias_mps2: float = 0.03
    accel_noise_density: float = 4e-3


@dataclass(frozen=True, slots=True)
class AxisVerdict:
    """What the FDI says about one axis after one measurement."""

    use: bool  # feed this sample to the observers that measure the axis
    residual_mps: float  # NaN if not computable
    test_ratio: float  # max over the tests of statistic/threshold; > 1 fails
    state: AxisState


@dataclass
class _Vetted:
    t_s: float
    z_mps: float


@dataclass
class AxisMonitor:
    """FDI of one NED axis."""

    axis: AxisName
    cfg: FdiConfig
    state: AxisState = AxisState.WARMUP
    fault: FaultEvent | None = None
    bias_mps2: float = 0.0
    _vetted: deque[_Vetted] = field(default_factory=deque)
    _pending: deque[tuple[float, float, bool]] = field(default_factory=deque)
    _resid: deque[float] = field(default_factory=deque)
    _last_y: float = math.nan
    _repeats: int = 0
    _nan_run: int = 0
    _fail_run: int = 0
    _fail_kind: FaultKind | None = None
    _healthy_since_s: float | None = None
    _t_first_s: float | None = None
    _t_isolated_s: float = 0.0
    _ref: tuple[float, float] | None = None  # (z̄, τ̄) frozen while isolated
    _ref_live: tuple[float, float] | None = None
    _bias_fitted: bool = False
    _fault_level_mps: float = 0.0  # |median residual| when a bias fault was isolated

    # ------------------------------------------------------------------ reference
    def reference(self) -> tuple[float, float] | None:
        """(z̄, τ̄): the vetted mean of z = y − A and its mean time; None before warm-up."""
        if self._ref is not None:
            return self._ref
        return self._ref_live

    def _update_reference(self) -> None:
        v = self._vetted
        if not v or not self._armed():
            self._ref_live = None
            return
        t_end = v[-1].t_s - self.cfg.reference_window_s
        zs = [s.z_mps for s in v if s.t_s >= t_end]
        ts = [s.t_s for s in v if s.t_s >= t_end]
        self._ref_live = (math.fsum(zs) / len(zs), math.fsum(ts) / len(ts))

    def _armed(self) -> bool:
        """Tests need a vetted reference and a bias fit (``warmup_s`` of vetted samples)."""
        v = self._vetted
        return self._bias_fitted and bool(v) and v[-1].t_s - v[0].t_s >= self.cfg.warmup_s

    def predict_mps(self, t_s: float, a_int_mps: float) -> float:
        """ŷ_j(t): the dead-reckoned velocity of this axis from the vetted reference."""
        ref = self.reference()
        if ref is None:
            return math.nan
        z_bar, t_bar = ref
        return z_bar + a_int_mps - self.bias_mps2 * (t_s - t_bar)

    def sigma_dead_reckoning_mps(self, t_s: float) -> float:
        """1σ of the prediction, growing with the time since the reference (bias, noise)."""
        ref = self.reference()
        age = 0.0 if ref is None else max(0.0, t_s - ref[1])
        c = self.cfg
        return math.sqrt(
            c.sigma_handover_mps**2
            + (c.sigma_bias_mps2 * age) ** 2
            + c.accel_noise_density**2 * age
        )

    def _vet(self, t_s: float) -> None:
        """Move pending samples older than the vetting delay into the reference.

        While the axis is isolated the reference and b̂ are frozen (nothing is vetted).
        """
        if self._ref is not None:
            return
        cfg = self.cfg
        n_before = len(self._vetted)
        while self._pending and self._pending[0][0] <= t_s - cfg.vet_delay_s:
            tp, zp, clean = self._pending.popleft()
            if clean:
                self._vetted.append(_Vetted(tp, zp))
        changed = False
        while self._vetted and self._vetted[0].t_s < t_s - cfg.vet_delay_s - cfg.bias_window_s:
            self._vetted.popleft()
            changed = True
        if changed or len(self._vetted) // 8 != n_before // 8:
            self._fit_bias()
        self._update_reference()

    def _fit_bias(self) -> None:
        """b̂ = −slope of z over the vetted window (least squares), if it spans ≥ 1 s."""
        v = self._vetted
        if len(v) < 10 or v[-1].t_s - v[0].t_s < 1.0:
            return
        t0 = v[0].t_s
        n = len(v)
        st = math.fsum(s.t_s - t0 for s in v)
        sz = math.fsum(s.z_mps for s in v)
        stt = math.fsum((s.t_s - t0) ** 2 for s in v)
        stz = math.fsum((s.t_s - t0) * s.z_mps for s in v)
        den = n * stt - st * st
        if den > 1e-12:
            self.bias_mps2 = -(n * stz - st * sz) / den
            self._bias_fitted = True

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

    def update(self, t_s: float, y_mps: float, a_int_mps: float) -> AxisVerdict:
        """One measurement of this axis at vehicle time ``t_s``; ``a_int_mps`` = A_j(t)."""
        cfg = self.cfg
        if self._t_first_s is None:
            self._t_first_s = t_s
        self._vet(t_s)
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
        pred = self.predict_mps(t_s, a_int_mps)
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
                kind = FaultKind.NOISE if noise_ratio > 1.0 else FaultKind.BIAS
                self._fail_run += 1
                self._fail_kind = kind
                self.state = AxisState.SUSPECT
                if self._fail_run >= cfg.k_isolate:
                    self._isolate(t_s, kind, onset_s=None)
                    return AxisVerdict(False, r, ratio, self.state)
            else:
                self._fail_run = 0
                self.state = AxisState.OK
            self._pending.append((t_s, y_mps - a_int_mps, not gated and not failing))
            return AxisVerdict(not gated and not repeated, r, ratio, self.state)
        # warm-up: no reference yet
        self._pending.append((t_s, y_mps - a_int_mps, not repeated))
        return AxisVerdict(not repeated, math.nan, ratio, self.state)

    def _isolate(self, t_s: float, kind: FaultKind, onset_s: float | None) -> None:
        self.state = AxisState.FAULTY
        self.fault = FaultEvent(self.axis, kind.value, t_s, onset_s)
        self._ref = self.reference()  # freeze the vetted reference: dead reckoning from here
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
            and not (noise_ratio > 1.0)
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
            self._ref = None  # the reference refreshes as samples after recovery are vetted
            self._resid.clear()
            return AxisVerdict(True, r, ratio, self.state)
        return AxisVerdict(False, r, ratio, self.state)

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
    axes: tuple[AxisMonitor, AxisMonitor, AxisMonitor] = field(init=False)

    def __post_init__(self) -> None:
        self.axes = (
            AxisMonitor("n", self.cfg),
            AxisMonitor("e", self.cfg),
            AxisMonitor("d", self.cfg),
        )

    def update(
        self, t_s: float, y_ned_mps: tuple[float, float, float], a_int_mps: list[float]
    ) -> tuple[AxisVerdict, AxisVerdict, AxisVerdict]:
        """One velocity measurement; the verdict per NED axis."""
        return (
            self.axes[0].update(t_s, y_ned_mps[0], a_int_mps[0]),
            self.axes[1].update(t_s, y_ned_mps[1], a_int_mps[1]),
            self.axes[2].update(t_s, y_ned_mps[2], a_int_mps[2]),
        )

    def faulty_axes(self) -> list[int]:
        """Indices (0 n, 1 e, 2 d) of the axes currently isolated, in isolation order."""
        idx = [i for i, a in enumerate(self.axes) if a.fault is not None]
        return sorted(idx, key=lambda i: self.axes[i]._t_isolated_s)

    def bias_ned_mps2(self) -> list[float]:
        """b̂: the earth-frame accelerometer bias estimate per axis (m/s²)."""
        return [a.bias_mps2 for a in self.axes]

    def states(self) -> dict[str, str]:
        return {ax: m.state.value for ax, m in zip(NED_AXES, self.axes, strict=True)}
