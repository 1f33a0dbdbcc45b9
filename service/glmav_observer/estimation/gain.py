"""The gain γ of ``full``: adapted to the noise a vehicle sends, lowered after a recovery.

Adaptation (``adapt_gamma_full``). Every ``update_samples`` (:class:`GainConfig`) measurements, while
every axis is healthy and armed, γ of ``full`` is set from the noise this vehicle sends
(:func:`~glmav_observer.estimation.observer.gamma_full_optimal`): the measurement's white
noise from successive residual differences, E[Δr²] = 2 σ_y² + q Δt_y, once every axis has
``scale_samples`` of them (``AxisMonitor.var_diff_mps2``); the IMU's (q) from the
despiker; the bias the bank still integrates (:func:`bias_left_mps2`, at least
``bias_floor_mps2``). A change is limited to ×/÷
``max_step_ratio`` per update, and one below ``min_change_fraction`` is not made
(:class:`GainConfig`).

Recovery blend. Back from a hand-over, ``full`` starts from the dead-reckoned estimate and
converges to the re-admitted measurement at ``gamma_full_min`` for ``recovery_blend_s``,
so that the dead reckoning's drift is corrected smoothly (in ~1/γ_min), not in one step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.despike import Despiker
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.fdi_reference import Reference
from glmav_observer.estimation.observer import gamma_full_optimal
from glmav_observer.estimation.reasons import const


@dataclass(frozen=True, slots=True)
class GainConfig:
    """The inner constants of the gain policy (not read from ``service.toml``; its bounds
    are ``gamma_full_min``/``gamma_full_max`` of ``[estimation]``)."""

    recovery_blend_s: float = const(
        1.0, unit="s", source="physics",
        reason="after a switch back to `full` its gain stays at gamma_full_min this long: "
        "the dead reckoning's drift is corrected in ~1/γ_min = 0.25 s (4 time constants "
        "in 1 s: 2 % left), not in one step",
    )  # fmt: skip
    update_samples: int = const(
        125, unit="samples", source="statistic",
        reason="measurements between two updates of γ: ~5 s at 25 Hz, enough for the "
        "running noise estimate to move (its memory is scale_samples = 250)",
    )  # fmt: skip
    max_step_ratio: float = const(
        1.5, unit="", source="requirement",
        reason="γ changes by at most ×/÷ this per update: from the default 12 to "
        "gamma_full_max (40) in 3 updates (15 s), so one noisy update cannot jump the gain",
    )  # fmt: skip
    min_change_fraction: float = const(
        0.02, unit="", source="statistic",
        reason="a change smaller than this fraction is not made: below the 4.5 % σ of the "
        "noise estimate it rests on (σ/√(2·250)), so the gain does not dither",
    )  # fmt: skip
    bias_floor_mps2: float = const(
        0.05, unit="m/s²", source="physics",
        reason="the accelerometer bias assumed by the optimal gain is at least this: the "
        "horizontal bias left after calibration plus g·sin of a 0.2° attitude error "
        "(as AidedAxisConfig.accel_bias_h_mps2); a fit that observed none is not a "
        "bias-free IMU",
    )  # fmt: skip


class FullGain:
    """The gain policy of ``full`` for one vehicle (module docstring)."""

    def __init__(
        self,
        adapt: bool,
        gamma_min: float,
        gamma_max: float,
        cfg: GainConfig | None = None,
        *,
        compensate_bias: bool = True,
    ) -> None:
        self.adapt = adapt
        #: the bank is fed the IMU less the fit's observed bias (selection.bank_bias)
        self.compensate_bias = compensate_bias
        self.gamma_min = gamma_min
        self.gamma_max = gamma_max
        self.cfg = cfg or GainConfig()
        self._n_meas = 0
        self._saved: float | None = None  # the gain before a recovery blend
        self._t_restore_s = math.inf

    def restore_if_due(self, t: float, bank: ObserverBank) -> None:
        """End a recovery blend at its time."""
        if t >= self._t_restore_s and self._saved is not None:
            bank.set_gamma("full", self._saved)
            self._saved = None
            self._t_restore_s = math.inf

    def blend_after_recovery(self, t: float, bank: ObserverBank) -> None:
        """``full`` was restarted from the dead-reckoned estimate: the low gain for a while."""
        if self._saved is None:
            self._saved = bank.gamma_gain[0]
        bank.set_gamma("full", min(self._saved, self.gamma_min))
        self._t_restore_s = t + self.cfg.recovery_blend_s

    def on_measurement(
        self,
        bank: ObserverBank,
        fdi: FaultDetector,
        despike: Despiker,
        imu_hz: float,
        y_interval_s: float,
    ) -> bool:
        """Count a measurement; every ``update_samples`` adapt γ. True if it changed."""
        self._n_meas += 1
        cfg = self.cfg
        if not self.adapt or self._n_meas % cfg.update_samples != 0:
            return False
        axes = fdi.axes
        if fdi.faulty_axes() or not fdi.armed() or y_interval_s <= 0.0 or self._saved is not None:
            return False
        if imu_hz <= 0.0 or any(a.n_diff < a.cfg.scale_samples for a in axes):
            return False  # (the noise estimate has not its full sample yet)
        q = despike.noise_var_mps2() / imu_hz
        # E[Δr²] = 2 σ_y² + q Δt_y (the IMU's white noise over one interval)
        var_y = max(min(a.var_diff_mps2 for a in axes) / 2.0 - q * y_interval_s / 2.0, 1e-8)
        b = max(bias_left_mps2(fdi.fit.ref, self.compensate_bias), cfg.bias_floor_mps2)
        target = gamma_full_optimal(
            math.sqrt(var_y), 1.0 / y_interval_s, q, b, self.gamma_min, self.gamma_max
        )
        now = bank.gamma_gain[0]
        step = cfg.max_step_ratio
        new = min(max(target, now / step), now * step)
        if abs(new - now) <= cfg.min_change_fraction * now:
            return False
        bank.set_gamma("full", new)
        return True


def bias_left_mps2(ref: Reference | None, compensated: bool) -> float:
    """The accelerometer bias ``full`` still integrates (m/s²), the b of J(γ): with the
    bias compensated (``compensate_accel_bias``: the bank is fed f − b̂ of the components
    the fit observed, ``selection.bank_bias``) what the fit did not observe plus the σ of
    its estimate, √Σ_k((b̂_k − b̂_obs,k)² + σ_k²); without, the whole fitted bias |b̂|;
    0 without a fit."""
    if ref is None:
        return 0.0
    if not compensated:
        return math.sqrt(sum(x * x for x in ref.bias_body_mps2))
    total = 0.0
    for k in (3, 4, 5):
        left = ref.theta[k] - ref.observed(k)
        total += left * left + max(float(ref.cov[k, k]), 0.0)
    return math.sqrt(total)
