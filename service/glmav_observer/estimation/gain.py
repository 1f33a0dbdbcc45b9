"""The gain γ of ``full``: adapted to the noise a vehicle sends, lowered after a recovery.

Adaptation (``adapt_gamma_full``). Every ``GAMMA_UPDATE_SAMPLES`` measurements, while
every axis is healthy and armed, γ of ``full`` is set from the noise this vehicle sends
(:func:`~glmav_observer.estimation.observer.gamma_full_optimal`): the measurement's white
noise from successive residual differences, E[Δr²] = 2 σ_y² + q Δt_y; the IMU's (q) from
the despiker; the bias from the fit (at least 0.05 m/s²). A change is limited to ×/÷ 1.5
per update.

Recovery blend. Back from a hand-over, ``full`` starts from the dead-reckoned estimate and
converges to the re-admitted measurement at ``gamma_full_min`` for ``RECOVERY_BLEND_S``,
so that the dead reckoning's drift is corrected smoothly (in ~1/γ_min), not in one step.
"""

from __future__ import annotations

import math

from glmav_observer.estimation.bank import ObserverBank
from glmav_observer.estimation.despike import Despiker
from glmav_observer.estimation.fdi import FaultDetector
from glmav_observer.estimation.observer import gamma_full_optimal

#: After a switch back to ``full``, its gain stays at ``gamma_full_min`` this long (s):
#: the dead reckoning's drift is corrected in ~1/γ_min = 0.25 s, not in one step.
RECOVERY_BLEND_S = 1.0
#: Measurements between two updates of the gain of ``full`` (~5 s at 25 Hz).
GAMMA_UPDATE_SAMPLES = 125


class FullGain:
    """The gain policy of ``full`` for one vehicle (module docstring)."""

    def __init__(self, adapt: bool, gamma_min: float, gamma_max: float) -> None:
        self.adapt = adapt
        self.gamma_min = gamma_min
        self.gamma_max = gamma_max
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
        self._t_restore_s = t + RECOVERY_BLEND_S

    def on_measurement(
        self,
        bank: ObserverBank,
        fdi: FaultDetector,
        despike: Despiker,
        imu_hz: float,
        y_interval_s: float,
    ) -> bool:
        """Count a measurement; every ``GAMMA_UPDATE_SAMPLES`` adapt γ. True if it changed."""
        self._n_meas += 1
        if not self.adapt or self._n_meas % GAMMA_UPDATE_SAMPLES != 0:
            return False
        axes = fdi.axes
        if fdi.faulty_axes() or not fdi.armed() or y_interval_s <= 0.0 or self._saved is not None:
            return False
        if imu_hz <= 0.0 or any(a.var_diff_mps2 <= 0.0 for a in axes):
            return False
        q = despike.noise_var_mps2() / imu_hz
        # E[Δr²] = 2 σ_y² + q Δt_y (the IMU's white noise over one interval)
        var_y = max(min(a.var_diff_mps2 for a in axes) / 2.0 - q * y_interval_s / 2.0, 1e-8)
        b = max(math.sqrt(sum(x * x for x in fdi.fit.bias_body_mps2)), 0.05)
        target = gamma_full_optimal(
            math.sqrt(var_y), 1.0 / y_interval_s, q, b, self.gamma_min, self.gamma_max
        )
        now = bank.gamma_gain[0]
        new = min(max(target, now / 1.5), now * 1.5)
        if abs(new - now) <= 0.02 * now:
            return False
        bank.set_gamma("full", new)
        return True
