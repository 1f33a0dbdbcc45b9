"""The lost axis's one-state Kalman filter and the rules that keep it from being worse than
dead reckoning (issue 13; the package docstring shows the calls).

:class:`AidedAxis` starts at the hand-over from the last measured value and σ, is
propagated at the IMU rate with the earth-frame acceleration (all three axes: the two
measured ones feed rule 1), and updated at the measurement rate with the drag model's
pseudo-measurement (:meth:`~glmav_observer.estimation.aero.model.DragModel.pseudo_measurement`)
and the two measured axes. It carries the plain dead reckoning of the lost axis alongside
(same propagation, never updated): every fall-back returns to it.

Four rules here decide when the pseudo-measurement is not fused (their reasons in
:class:`AidedAxisConfig`); rule 3 is the model's own, below (docs/design/observer-notes.md numbers
them the same):

1. **The measured axes must be consistent with the IMU** (the pseudo-measurement is
   computed from them: an error δ in a measured axis i moves the lost axis by
   δ·r_j,i/r_j,L). Each measured axis is tracked by an IMU-propagated prediction pulled
   towards the measurement with a 1 s time constant; a measurement whose innovation exceeds
   5σ (σ² = σ_meas² + the IMU's drift over that time constant: 1.06 m/s with the
   defaults) marks the measured axes *suspect*: the prediction then coasts on the IMU and
   nothing is fused (the lost axis dead-reckons from where it is) until every innovation
   is back inside the gate for 1 s; after 10 s of suspicion the prediction is
   re-synchronised to the measurement (a step that lasts is a new level, or the FDI's
   business).
2. **The pseudo-measurements must agree with the dead reckoning** they correct (a wind
   change, or a model used outside the data it learnt from: nothing measured reveals
   either directly; measured on ArduPilot's quads, pseudo-measurement errors of 2-4 times
   their σ during a loss). z² = (z − v_DR)²/(σ_z² + P_DR) is averaged
   over a 2 s exponential window of updates; above 1 the model is stale and the axis falls
   back to the dead reckoning from the hand-over for the rest of the loss. After a gap of
   2 s without pseudo-measurements the first one stands for the window and decides alone
   when z² > 9 (3σ). Why 1: P_DR
   is conservative (a bias of σ_b acting since the hand-over; on the corpus the dead
   reckoning's error stayed inside 2σ all the time), so a model and a dead reckoning that
   are both as good as their σ say disagree by less than their combined σ. Measured
   (docs/benchmarks/aero.md), the largest 2 s mean is 0.11-0.54 in the corpus cases where
   aiding beats dead reckoning (coax, heli) and 1.5-11 in the quad and heli cases where it
   did not (without this rule: 60 s RMS 1.02 vs 0.10 m/s, 10 s error 0.73 vs 0.12); one
   quad case stays at 0.52, indistinguishable, and remains 0.05 m/s (RMS) worse than dead
   reckoning. The price: when the residual bias exceeds σ_b (0.05 m/s²) the rule cannot
   tell the IMU from the model and falls back too (never worse than dead reckoning, but
   the aiding's benefit is lost).

4. **The pseudo-measurements must not scatter beyond their σ** (a model biased out of
   sample: ArduPilot's quad, whose frozen model's errors are 2-4σ and vary within
   seconds, while rule 2 cannot see them against a dead reckoning whose σ has grown).
   d = z − v_DR is fitted by an exponentially weighted local line over time (time
   constant 10 s: a bias-driven dead-reckoning error is a ramp, which the slope takes up;
   the model part of σ, correlated over 10 s, moves with it); each new d's residual about
   the line's prediction, squared and normalised by σ_z², is averaged over a 10 s
   exponential window of updates; above 2 (scatter beyond √2 σ; a pseudo-measurement as
   good as its σ stays ≲ 1) the axis falls back to the dead reckoning from the hand-over
   for the rest of the loss. Judged once the line has 1 s of data and the window most of
   its weight. Measured (docs/benchmarks/aero.md): 1.5-17 median per loss on the quad,
   ≤ 1.6 at any time on the coax and heli.
5. **The estimate must stay better than the dead reckoning by its own σ.** After an
   update P ≥ σ_m² (the model part, common to every update); when that is not below
   P_DR (a model used far from its data early in a loss, while P_DR is small) the axis
   takes the dead reckoning's value and variance instead, and aiding goes on from there
   (not a stop).

Rule 3 is the model's own (:class:`~glmav_observer.estimation.aero.model.DragModel`,
"changing"): a model that was being contradicted by its data when the axis was lost (a
wind change) gives no pseudo-measurement for that loss.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from glmav_observer.estimation.aero.model import DragModel, FloatArray, PseudoMeasurement


@dataclass(frozen=True, slots=True)
class AidedAxisConfig:
    """Noise model of :class:`AidedAxis` and its rules (module docstring)."""

    #: white noise of the earth-frame acceleration, m/s²/√Hz (accelerometer noise density
    #: of a small MEMS IMU with vibration, ~0.05; integrates to σ·√t)
    accel_noise_mps2_rthz: float = 0.05
    #: unknown constant error of the earth-frame acceleration, m/s², integrating to σ·t.
    #: Horizontal (n, e): accelerometer bias left after calibration (~0.02) plus g·sin of
    #: the attitude estimate's error (~0.2°: 0.035), ≈ 0.05. Vertical (d): the attitude
    #: error enters only at second order (g·(1 − cos)), so the bias alone, 0.02
    accel_bias_h_mps2: float = 0.05
    accel_bias_v_mps2: float = 0.02
    #: gate: an update whose |innovation| > gate_sigma · √(P + R) is rejected
    gate_sigma: float = 5.0
    #: correlation time of the pseudo-measurement's white part, s: updates closer than
    #: this are not independent (turbulence, manoeuvres), so R is inflated by τ_c/Δt
    corr_time_s: float = 1.0
    #: correlation time of its model part (the coefficients' error: changes only as the
    #: attitude does), s; R's model part is inflated by τ_m/Δt likewise
    model_corr_time_s: float = 10.0
    #: this many rejections in a row and aiding stops (the model no longer fits)
    max_rejections: int = 50
    #: rule 1: noise of the measured axes' velocity against a 1 s IMU prediction, m/s: a
    #: filtered, lagging velocity (GPS through an EKF) is off by the acceleration times
    #: its lag during manoeuvres; measured, the innovation reaches 0.19 m/s on the
    #: ArduPilot corpus and 0.53 m/s on glmav-sitl's autopilot profile, so 0.2 (gate 1.06,
    #: twice the largest seen)
    sigma_v_meas_mps: float = 0.2
    #: rule 1: time constant of the measured axes' IMU-propagated prediction, s. Its
    #: innovation's σ is √(σ_meas² + σ_n² T + (σ_b T)²) = 0.21 m/s with the defaults
    meas_track_time_s: float = 1.0
    #: rule 1: gate on that innovation, in σ (1.06 m/s with the defaults; a Gaussian
    #: innovation fails a 5σ gate in 6e-7 of the samples; none of the benchmark's 60 000)
    meas_gate_sigma: float = 5.0
    #: rule 1: the measured axes stay suspect this long after their last failed gate, s
    meas_holdoff_s: float = 1.0
    #: rule 1: after this long suspect, the prediction is re-synchronised, s
    meas_resync_s: float = 10.0
    #: rule 2: window of the z² average (exponential, over update time), s
    stale_window_s: float = 2.0
    #: rule 2: the average z² above this and the model is stale (module docstring: the
    #: dead reckoning's σ is conservative, so a consistent pair stays below 1; measured
    #: ≤ 0.54 where the model holds)
    stale_nees_max: float = 1.0
    #: rule 2: the first pseudo-measurement after a gap of ``stale_window_s`` decides
    #: alone above this z² (3σ)
    stale_gap_z2: float = 9.0
    #: rule 4: time constant of the local linear trend of d = z − v_DR the scatter is
    #: measured about, s. Long enough to hold many of the pseudo-measurement's white
    #: correlation times (``corr_time_s``, 1 s) and as long as its model part's
    #: (``model_corr_time_s``, 10 s: that part moves with the trend and is not scatter);
    #: the dead reckoning's own error over it is a ramp (a constant bias), which the
    #: trend's slope takes up
    scatter_trend_s: float = 10.0
    #: rule 4: window of the mean normalised scatter (exponential, over update time), s:
    #: ~10 correlation times of the white part, so a pseudo-measurement whose σ is right
    #: exceeds a mean of 2 with ~3 % probability per window (χ² with 10 degrees of freedom
    #: / 10); a fitting model's is also well below 1 (σ is conservative: measured
    #: median 0.04-0.5, largest 1.6, on the corpus coax and heli)
    scatter_window_s: float = 10.0
    #: rule 4: the mean normalised scatter above this and the model's σ is not to be
    #: believed (its pseudo-measurements scatter more than √2 σ about their own trend):
    #: the axis falls back to dead reckoning. (Measured on the corpus quad, whose model
    #: is biased out of sample: 1.5-17 median per loss; docs/design/observer-notes.md)
    scatter_max: float = 2.0
    #: rule 4: the trend extrapolates at least this long of its own data before its
    #: residual is judged, s (one white correlation time: a slope fitted to less is one
    #: correlated blob)
    scatter_trend_min_s: float = 1.0
    #: a pseudo-measurement whose σ exceeds this is not made (``DragModel.
    #: pseudo_measurement``'s ``sigma_max_mps``), m/s. Off (∞): the filter weighs each by
    #: its σ (R, inflated by the correlation times) and rule 5 refuses one that cannot
    #: beat dead reckoning; a cap of 1 m/s refused every pseudo-measurement in a hover in
    #: turbulence, whose average is what the floor shows possible (issue 32)
    pm_sigma_max_mps: float = field(
        default=math.inf,
        metadata={
            "unit": "m/s",
            "source": "requirement",
            "reason": "a pseudo-measurement less certain than this is not made",
        },
    )


class AidedState(NamedTuple):
    """The lost axis: velocity (m/s), its 1σ (m/s), whether the last accepted
    pseudo-measurement is recent (aided) or the axis is dead-reckoned, and why."""

    v_mps: float
    sigma_mps: float
    aided: bool
    why: str = ""


class AidedAxis:
    """One-state Kalman filter of a lost NED velocity axis (m/s).

    Process model: v̇ = a_L + b + n, with a_L the IMU's earth-frame acceleration of the
    axis, b an unknown constant error of σ ``accel_bias_mps2`` and n white noise of density
    ``accel_noise_mps2_rthz``. A one-state filter cannot carry b, so the variance grows as
    it would under a constant b since the hand-over, τ seconds ago:

        P ← P + (σ_n² + 2 σ_b² τ) Δt        (pure propagation: P = P₀ + σ_n² t + σ_b² t²)

    Update with a pseudo-measurement z (σ_z, model part σ_m): innovation ν = z − v,
    R = (σ_z² − σ_m²) · max(1, τ_c/Δt_u) + σ_m²·max(1, τ_m/Δt_u); rejected when
    |ν| > 5 √(P + σ_z²); after an accepted update P ≥ σ_m² (the coefficient error is the
    same in every pseudo-measurement and is not averaged away). ``max_rejections`` in a
    row, a broken model, rule 2 or rule 4 (module docstring) stop the aiding for good and
    put the axis back on the dead reckoning; rule 1 suspends it; rule 5 puts the axis back
    on the dead reckoning for that update only.
    """

    def __init__(
        self,
        lost_axis: int,
        v0_mps: float,
        sigma0_mps: float,
        t0_s: float = 0.0,
        config: AidedAxisConfig | None = None,
        *,
        drift_rate_mps2: float | None = None,
    ) -> None:
        if lost_axis not in (0, 1, 2):
            raise ValueError(f"lost_axis must be 0, 1 or 2, got {lost_axis!r}")
        self.lost_axis = lost_axis
        self.config = config or AidedAxisConfig()
        #: the vehicle's measured dead-reckoning drift rate on this axis, m/s² (None: not
        #: measured; :mod:`.drift_rate`): the published σ takes it where it exceeds the
        #: prior σ_b (it must cover the error), propagated with the filter's own gains
        #: (Joseph form); the filter's gains and rules keep the prior
        self.drift_rate_mps2 = drift_rate_mps2
        cfg = self.config
        sigma_b = cfg.accel_bias_v_mps2 if lost_axis == 2 else cfg.accel_bias_h_mps2
        self._sigma_b_mps2 = sigma_b
        self._sigma_b_pub_mps2 = sigma_b
        if drift_rate_mps2 is not None and math.isfinite(drift_rate_mps2):
            self._sigma_b_pub_mps2 = max(sigma_b, drift_rate_mps2)
        self.v_mps = float(v0_mps)
        #: the filter's variance (its gains and rules) and the published one, m²/s²
        self.P_mps2 = float(sigma0_mps) ** 2
        self.P_pub_mps2 = self.P_mps2
        #: dead reckoning from the hand-over, kept for the fall-back
        self.v_dr_mps = self.v_mps
        self.P_dr_mps2 = self.P_mps2
        self.P_dr_pub_mps2 = self.P_mps2
        self.t_s = t0_s
        self._tau_s = 0.0  # time since the hand-over (the unestimated bias acts since then)
        self._since_update_s = math.inf  # time since the last accepted update
        self._t_update_s: float | None = None
        self.n_accepted = 0
        self.n_rejected = 0
        #: rule 5: updates that set the axis back on the dead reckoning (σ not below its)
        self.n_dr_better = 0
        self._dr_better = False
        self._rejections_in_row = 0
        self.stopped = False
        #: why the aiding stopped ("" while it has not)
        self.stop_reason = ""
        #: rule 1: the measured axes' IMU-propagated prediction (None before the first
        #: update with measurements), when they were last outside the gate, since when
        #: they are suspect, and how many updates were skipped for it
        self._meas_axes = tuple(i for i in range(3) if i != lost_axis)
        self._v_hat: list[float] | None = None
        self._t_meas_s: float | None = None
        self._meas_bad_t_s = -math.inf
        self._meas_suspect_since_s: float | None = None
        self.n_meas_suspect = 0
        #: the last pseudo-measurement :meth:`update_from_model` made (None: none)
        self.last_pm: PseudoMeasurement | None = None
        #: rule 2: exponential average of z² against the dead reckoning and its weight
        self._stale_z2 = 0.0
        self._stale_w = 0.0
        #: rule 4: exponentially weighted sums of the trend's fit of d = z − v_DR against
        #: the time since the hand-over (Σw, Σwt, Σwt², Σwd, Σwtd), and the mean scatter
        self._trend = [0.0] * 5
        self._scatter_z2 = 0.0
        self._scatter_w = 0.0

    # ------------------------------------------------------------------ IMU rate
    def propagate(self, dt_s: float, a_ned_mps2: Sequence[float]) -> None:
        """Advance by ``dt_s`` with the IMU's earth-frame acceleration (n, e, d), m/s²
        (E Γ less the compensated accelerometer bias): the lost axis's component moves
        the estimate, the other two the measured axes' prediction (rule 1)."""
        a_lost = float(a_ned_mps2[self.lost_axis])
        if dt_s <= 0.0 or not math.isfinite(a_lost):
            return
        cfg = self.config
        # exact integral of σ_n² + 2 σ_b² τ over [τ, τ + Δt]
        d_white = cfg.accel_noise_mps2_rthz**2 * dt_s
        d_tau2 = (self._tau_s + dt_s) ** 2 - self._tau_s**2
        dP = d_white + self._sigma_b_mps2**2 * d_tau2
        dP_pub = d_white + self._sigma_b_pub_mps2**2 * d_tau2
        self.v_mps += a_lost * dt_s
        self.P_mps2 += dP
        self.P_pub_mps2 += dP_pub
        self.v_dr_mps += a_lost * dt_s
        self.P_dr_mps2 += dP
        self.P_dr_pub_mps2 += dP_pub
        self._tau_s += dt_s
        self._since_update_s += dt_s
        self.t_s += dt_s
        if self._v_hat is not None:
            for n, i in enumerate(self._meas_axes):
                a_i = float(a_ned_mps2[i])
                if math.isfinite(a_i):
                    self._v_hat[n] += a_i * dt_s

    # ------------------------------------------------------------------ measurement rate
    def update_from_model(
        self,
        model: DragModel,
        f_mean_body_mps2: Sequence[float],
        E: FloatArray,
        v_meas_ned_mps: Sequence[float],
        *,
        relative_to_mps: float = 0.0,
        control: tuple[float, float] | None = None,
    ) -> bool:
        """One velocity measurement during the loss: the measured axes are checked first
        (rule 1: a suspect measurement is not even turned into a pseudo-measurement, so it
        cannot mark the model broken either), then the model's pseudo-measurement of the
        lost axis (:meth:`DragModel.pseudo_measurement` from the mean specific force over
        the interval, FRD m/s², E body→NED and the NED measurement, its lost entry ignored)
        is fused by :meth:`update`. True when a pseudo-measurement was accepted; the last
        one (or None) is kept in :attr:`last_pm`.

        ``relative_to_mps``: the filter's state is the lost axis's offset from a dead
        reckoning kept elsewhere (the estimator's bank, propagated with the lost axis's
        acceleration set to 0 here), whose value now this is: the pseudo-measurement is
        fused as its difference from it, and a stop falls back to offset 0, that dead
        reckoning itself. ``control``: the cyclic regressors of a model that uses them
        (:mod:`.control`)."""
        self.last_pm = None
        if self._measured_axes_suspect(v_meas_ned_mps):
            self.n_meas_suspect += 1
            return False
        if self.stopped:
            return False
        self.last_pm = model.pseudo_measurement(
            np.asarray(f_mean_body_mps2),
            E,
            np.asarray(v_meas_ned_mps),
            self.lost_axis,
            sigma_max_mps=self.config.pm_sigma_max_mps,
            control=control,
        )
        pm = self.last_pm
        if pm is not None and relative_to_mps != 0.0:
            pm = PseudoMeasurement(pm.v_mps - relative_to_mps, pm.sigma_mps, pm.sigma_model_mps)
        return self.update(pm, model_broken=model.broken)

    def update(
        self,
        pm: PseudoMeasurement | None,
        *,
        v_meas_ned_mps: Sequence[float] | None = None,
        model_broken: bool = False,
    ) -> bool:
        """Fuse a pseudo-measurement (None: nothing to fuse). True when accepted.

        ``v_meas_ned_mps``: the NED velocity measured at this update (the lost axis's
        entry is ignored), the one the pseudo-measurement was computed from; rule 1 checks
        its two measured axes (None: not checked). ``model_broken``
        (:attr:`DragModel.broken`): aiding stops and the axis falls back to dead
        reckoning from the hand-over, so a model that went wrong leaves nothing behind."""
        if model_broken:
            self._stop("the drag model's two rows disagree")
        if v_meas_ned_mps is not None and self._measured_axes_suspect(v_meas_ned_mps):
            self.n_meas_suspect += 1
            return False
        if pm is None or self.stopped:
            return False
        cfg = self.config
        dt_u = cfg.corr_time_s if self._t_update_s is None else self.t_s - self._t_update_s
        self._t_update_s = self.t_s
        dt_u = max(dt_u, 1e-6)
        if self._stale(pm, dt_u):
            self._stop("the pseudo-measurements disagree with dead reckoning")
            return False
        if self._scatters(pm, dt_u):
            self._stop("the pseudo-measurements scatter beyond their σ")
            return False
        var_m = pm.sigma_model_mps**2
        var_white = max(pm.sigma_mps**2 - var_m, 0.0)
        R = var_white * max(1.0, cfg.corr_time_s / dt_u) + var_m * max(
            1.0, cfg.model_corr_time_s / dt_u
        )
        nu = pm.v_mps - self.v_mps
        S = self.P_mps2 + R
        # the gate uses the pseudo-measurement's own σ (not the correlation-inflated R)
        if nu * nu > cfg.gate_sigma**2 * (self.P_mps2 + pm.sigma_mps**2):
            self.n_rejected += 1
            self._rejections_in_row += 1
            if self._rejections_in_row >= cfg.max_rejections:
                # the pseudo-measurements and the estimate parted: one of them went wrong
                # and the filter cannot tell which; dead reckoning is the safe side
                self._stop(f"{cfg.max_rejections} rejections in a row")
            return False
        K = self.P_mps2 / S
        P_post = max((1.0 - K) * self.P_mps2, var_m)
        self._rejections_in_row = 0
        if P_post >= self.P_dr_mps2:
            # rule 5: after the update the estimate would be no better than the dead
            # reckoning by its own σ (the model part σ_m, common to every
            # pseudo-measurement, exceeds the dead reckoning's σ: a model used far from
            # its data). The better of the two is the dead reckoning: the axis takes it,
            # and the next pseudo-measurement starts from there (not a stop)
            self.v_mps, self.P_mps2 = self.v_dr_mps, self.P_dr_mps2
            self.P_pub_mps2 = self.P_dr_pub_mps2
            self._since_update_s = math.inf
            self._dr_better = True
            self.n_dr_better += 1
            return False
        self._dr_better = False
        self.v_mps += K * nu
        self.P_mps2 = P_post
        if self._sigma_b_pub_mps2 == self._sigma_b_mps2:
            self.P_pub_mps2 = P_post  # the same noise model: the same variance
        else:
            # the published variance with this gain (Joseph form: right for any gain)
            self.P_pub_mps2 = max((1.0 - K) ** 2 * self.P_pub_mps2 + K * K * R, var_m)
        self._since_update_s = 0.0
        self.n_accepted += 1
        return True

    def _stop(self, reason: str) -> None:
        if not self.stopped:
            self.stopped = True
            self.stop_reason = reason
            self.v_mps, self.P_mps2 = self.v_dr_mps, self.P_dr_mps2
            self.P_pub_mps2 = self.P_dr_pub_mps2

    def _measured_axes_suspect(self, v_meas_ned_mps: Sequence[float]) -> bool:
        """Rule 1 (module docstring): True while the measured axes are suspect."""
        cfg = self.config
        v = [float(v_meas_ned_mps[i]) for i in self._meas_axes]
        if not all(math.isfinite(x) for x in v):
            self._meas_bad_t_s = self.t_s
            return True
        if self._v_hat is None or self._t_meas_s is None:
            self._v_hat = v
            self._t_meas_s = self.t_s
            return False
        dt = max(self.t_s - self._t_meas_s, 0.0)
        self._t_meas_s = self.t_s
        T = cfg.meas_track_time_s
        sigma_b = cfg.accel_bias_v_mps2 if 2 in self._meas_axes else cfg.accel_bias_h_mps2
        var_nu = cfg.sigma_v_meas_mps**2 + cfg.accel_noise_mps2_rthz**2 * T + (sigma_b * T) ** 2
        bad = any(
            (x - xh) ** 2 > cfg.meas_gate_sigma**2 * var_nu
            for x, xh in zip(v, self._v_hat, strict=True)
        )
        if bad:
            self._meas_bad_t_s = self.t_s
            if self._meas_suspect_since_s is None:
                self._meas_suspect_since_s = self.t_s
            elif self.t_s - self._meas_suspect_since_s >= cfg.meas_resync_s:
                self._v_hat = v  # a step that lasts: the new level
                self._meas_suspect_since_s = None
            return True
        alpha = min(1.0, dt / T)
        self._v_hat = [xh + alpha * (x - xh) for x, xh in zip(v, self._v_hat, strict=True)]
        if self.t_s - self._meas_bad_t_s < cfg.meas_holdoff_s:
            return True
        self._meas_suspect_since_s = None
        return False

    def _stale(self, pm: PseudoMeasurement, dt_u: float) -> bool:
        """Rule 2 (module docstring): True when the pseudo-measurements have disagreed with
        the dead reckoning by more than their combined σ (mean z² > ``stale_nees_max``)
        over the last ``stale_window_s``."""
        cfg = self.config
        z2 = (pm.v_mps - self.v_dr_mps) ** 2 / (pm.sigma_mps**2 + self.P_dr_mps2)
        # exponential forgetting over time; each update weighs the time it stands for, at
        # most 0.2 s (a 5 Hz GPS's interval), so after a gap without pseudo-measurements
        # the window refills before it is judged, rather than on the first sample
        decay = math.exp(-dt_u / cfg.stale_window_s)
        w = min(dt_u, 0.2) / cfg.stale_window_s
        self._stale_z2 = decay * self._stale_z2 + w * z2
        self._stale_w = decay * self._stale_w + w
        # after a gap as long as the window, the first pseudo-measurement stands for the
        # whole window: it decides alone when beyond 3σ (a consistent pair: 0.27 % of such
        # samples, a few per loss; measured: the heli's 3.3 m/s jump after a 3.4 s gap)
        if dt_u >= cfg.stale_window_s and z2 > cfg.stale_gap_z2:
            return True
        # judged once the window holds most of its weight (1 − e⁻¹: ~2 s of updates)
        full = self._stale_w >= 1.0 - math.exp(-1.0)
        return full and self._stale_z2 > cfg.stale_nees_max * self._stale_w

    def _scatters(self, pm: PseudoMeasurement, dt_u: float) -> bool:
        """Rule 4 (module docstring): True when the pseudo-measurements scatter about their
        own local linear trend against the dead reckoning by more than ``scatter_max``
        times their variance (mean over ``scatter_window_s``)."""
        cfg = self.config
        d = pm.v_mps - self.v_dr_mps
        t = self._tau_s
        if dt_u > cfg.scatter_trend_s:
            # a gap longer than the trend: it no longer says where d is going
            self._trend = [0.0] * 5
        lam = math.exp(-dt_u / cfg.scatter_trend_s)
        sw, swt, swt2, swd, swtd = (lam * x for x in self._trend)
        w = min(dt_u, 0.2)  # the time this update stands for (rule 2's weighting)
        judged = False
        if sw >= cfg.scatter_trend_min_s:
            t_mean = swt / sw
            var_t = swt2 / sw - t_mean * t_mean
            d_mean = swd / sw
            slope = (swtd / sw - t_mean * d_mean) / var_t if var_t > 1e-9 else 0.0
            z2 = (d - d_mean - slope * (t - t_mean)) ** 2 / pm.sigma_mps**2
            decay = math.exp(-dt_u / cfg.scatter_window_s)
            self._scatter_z2 = decay * self._scatter_z2 + w / cfg.scatter_window_s * z2
            self._scatter_w = decay * self._scatter_w + w / cfg.scatter_window_s
            judged = self._scatter_w >= 1.0 - math.exp(-1.0)
        self._trend = [sw + w, swt + w * t, swt2 + w * t * t, swd + w * d, swtd + w * t * d]
        return judged and self._scatter_z2 > cfg.scatter_max * self._scatter_w

    @property
    def scatter_mean_z2(self) -> float:
        """Rule 4's statistic now: the mean normalised scatter (NaN before it is judged)."""
        if self._scatter_w < 1.0 - math.exp(-1.0):
            return math.nan
        return self._scatter_z2 / self._scatter_w

    def state(self, aided_within_s: float = 1.0) -> AidedState:
        """(v, σ, aided, why): aided while an update was accepted in the last
        ``aided_within_s`` seconds."""
        aided = self._since_update_s <= aided_within_s and not self.stopped
        if self.stopped:
            why = f"dead reckoning: {self.stop_reason}"
        elif aided:
            why = "aided"
        elif self._dr_better:
            why = "dead reckoning: the model's σ is not below dead reckoning's"
        elif self.t_s - self._meas_bad_t_s < self.config.meas_holdoff_s:
            why = "dead reckoning: measured axes inconsistent with the IMU"
        else:
            why = "dead reckoning: no pseudo-measurement"
        return AidedState(self.v_mps, math.sqrt(self.P_pub_mps2), aided, why)
