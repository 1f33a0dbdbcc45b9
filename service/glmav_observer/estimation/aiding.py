"""The lost axis aided by the learnt drag model: the ``aided`` configuration (issue 13).

While every axis is healthy and armed, the drag model (:class:`~glmav_observer.
estimation.aero.DragModel`) learns from each velocity measurement: the body-frame specific
force averaged over the interval since the previous one, E and the measured velocity.
When an axis is isolated, the hand-over configuration dead-reckons it (the bank,
:mod:`~glmav_observer.estimation.selection`) and the ``aided`` estimate is that
configuration with its lost axis corrected by a one-state filter (:class:`~glmav_observer.
estimation.aero.AidedAxis`) on the *offset* δ between the aided and the dead-reckoned
value:

    δ̇ = noise (the bank integrates the lost axis's acceleration: one propagation),
    z = pseudo-measurement − dead-reckoned value,   v_aided = v_dr + δ,

started at δ = 0 with the hand-over's σ. The filter is propagated with the earth-frame
acceleration the bank is fed (E (f − b̂_obs) + g e_d) with the lost component set to 0: the
measured axes' components feed its check of the measured axes against their IMU
prediction. Its rules keep it from being worse than dead reckoning (the model's own tests;
measured axes that disagree with their IMU prediction; pseudo-measurements that disagree
with the dead reckoning: docs/design/observer-notes.md); when one fires it stops, δ goes back to 0 and
the ``aided`` estimate *is* the bank's dead reckoning, the ``active`` one.

With ``[estimation] aero_active`` (the default) the ``active`` estimate is the ``aided``
one while the aiding runs (:meth:`LostAxisAiding.active_offset`): the published offset
from the dead reckoning is the filter's. When the filter drops its offset (a rule stops
it, rule 5 sets it back on the dead reckoning, a second axis is isolated) the active
estimate does not jump back: the dropped part returns to the dead reckoning
exponentially over ``RETURN_TIME_S`` (a switch of the estimate, bounded like a
hand-over's: by < 0.05 m/s from one record to the next at ≥ 50 Hz).

With a channel map (``[estimation.aero_control]``, :class:`~glmav_observer.estimation.aero.
control.ControlMapping`), the vehicle's latest ``SERVO_OUTPUT_RAW`` is held here and its
cyclic regressors (C1) enter the model: on the first usable one the model is replaced by one
with the control term (:attr:`DragModelConfig.control`; nothing learnt is lost that
early); a vehicle that never sends it keeps the drag model alone.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from glmav_observer.estimation.aero import (
    AidedAxis,
    AidedAxisConfig,
    AidedState,
    DragModel,
    DragModelConfig,
)
from glmav_observer.estimation.aero.control import ControlMapping
from glmav_observer.estimation.aero.drift_rate import DriftRate

Vec3 = tuple[float, float, float]

#: time constant of the active estimate's return to the dead reckoning when the aided
#: offset is dropped, s. A dropped offset of up to 1 m/s (the largest on the corpus:
#: 0.9 m/s, f_coax_clean n at 65.2 s) then moves the estimate by ≤ 1 · Δt/τ = 0.02 m/s
#: per record at the corpus's 50 Hz IMU, inside the hand-over's 0.05 m/s jump bound
#: (benchmarks/corpus.py); after 3 s (3τ) 5 % of it is left
RETURN_TIME_S = 1.0


class LostAxisAiding:
    """The drag model of one vehicle and, while an axis is lost, its aided filter."""

    def __init__(
        self,
        sigma_handover_mps: float,
        model_config: DragModelConfig | None = None,
        axis_config: AidedAxisConfig | None = None,
        control: ControlMapping | None = None,
    ) -> None:
        self.model = DragModel(model_config)
        #: the dead reckoning's drift measured while healthy (the published σ of the lost
        #: axis covers at least it: :mod:`~glmav_observer.estimation.aero.drift_rate`)
        self.drift = DriftRate()
        self.axis_config = axis_config
        self.sigma_handover_mps = sigma_handover_mps
        self._axis: AidedAxis | None = None
        self.control = control
        #: the latest cyclic regressors (ρ_x, ρ_y) and their vehicle time
        self._rho: tuple[float, float] | None = None
        self._t_rho_s = 0.0
        self._reset_offset()

    def _reset_offset(self) -> None:
        #: the active estimate's offset: the part dropped by the filter and still
        #: returning (m/s), the last record's time and offset from the filter, and how
        #: many times the filter had dropped its offset then (stops and rule 5)
        self._return_mps = 0.0
        self._t_offset_s: float | None = None
        self._filter_offset_mps = 0.0
        self._drops = 0
        self._running = False

    def hold_control(self, t_s: float, servo_pwm_us: tuple[int, ...]) -> None:
        """A SERVO_OUTPUT_RAW: held (with a channel map; else ignored)."""
        if self.control is None:
            return
        rho = self.control.regressors(servo_pwm_us)
        if rho is None:
            return
        if not self.model.config.control and self._axis is None:
            self.model = DragModel(dataclasses.replace(self.model.config, control=True))
        self._rho = rho
        self._t_rho_s = t_s

    def _control_at(self, t_s: float) -> tuple[float, float] | None:
        """The held regressors when fresh (``ControlMapping.max_age_s``), else None."""
        if self.control is None or self._rho is None:
            return None
        return self._rho if t_s - self._t_rho_s <= self.control.max_age_s else None

    @property
    def lost_idx(self) -> int | None:
        return None if self._axis is None else self._axis.lost_axis

    def learn(
        self,
        t_s: float,
        f_mean_body_mps2: Vec3,
        e_flat: list[float],
        v_ned_mps: Vec3,
        *,
        a_int_ned_mps: Sequence[float] | None = None,
        b_int_flat_s: Sequence[float] | None = None,
    ) -> None:
        """A healthy measurement (every axis measured and vetted by the FDI); with the
        estimator's integrals then (A = ∫EΓ dt, B = ∫E dt, ``HeldInputs``) the dead
        reckoning's drift is measured too."""
        self.model.learn_flat(t_s, f_mean_body_mps2, e_flat, v_ned_mps, self._control_at(t_s))
        if a_int_ned_mps is not None and b_int_flat_s is not None:
            self.drift.observe(t_s, a_int_ned_mps, b_int_flat_s, v_ned_mps)

    def start(self, t_s: float, lost_idx: int) -> None:
        """Axis ``lost_idx`` is lost at ``t_s``: the offset starts at 0, σ the hand-over's
        (the new configuration starts from the published active estimate: nothing to
        return)."""
        rate = self.drift.rate_mps2()
        self._axis = AidedAxis(
            lost_idx,
            0.0,
            self.sigma_handover_mps,
            t_s,
            self.axis_config,
            drift_rate_mps2=None if rate is None else rate[lost_idx],
        )
        self._reset_offset()

    def stop(self) -> None:
        self._axis = None
        self._reset_offset()

    def restart(self) -> None:
        """The estimator starts afresh (its integrals too): stop, and forget the drift
        measured on the old integrals (the model is kept: a vehicle fact)."""
        self.stop()
        self.drift.clear()

    def propagate(self, dt_s: float, a_ned_mps2: list[float]) -> None:
        """Over a step, with the earth-frame acceleration the bank was fed (m/s²; the lost
        axis's component is the bank's to integrate, not the offset's)."""
        axis = self._axis
        if axis is not None:
            a = list(a_ned_mps2)
            a[axis.lost_axis] = 0.0
            axis.propagate(dt_s, a)

    def update(
        self,
        f_mean_body_mps2: Vec3,
        e_flat: list[float],
        v_meas_ned_mps: Vec3,
        v_dr_mps: float,
        t_s: float = 0.0,
    ) -> None:
        """A measurement at ``t_s`` while the axis is lost (its lost entry is not used);
        ``v_dr_mps`` the lost axis's dead-reckoned value now."""
        if self._axis is not None:
            self._axis.update_from_model(
                self.model,
                f_mean_body_mps2,
                _e(e_flat),
                v_meas_ned_mps,
                relative_to_mps=v_dr_mps,
                control=self._control_at(t_s),
            )

    def active_offset(self, t_s: float, filter_offset_mps: float | None) -> float:
        """The offset of the active estimate's lost axis from its dead reckoning at a
        record (``aero_active``): the filter's (``filter_offset_mps``, None while the
        aiding does not run) plus what it dropped since the last record, returning to 0
        with ``RETURN_TIME_S`` (module docstring)."""
        axis = self._axis
        target = 0.0 if filter_offset_mps is None else filter_offset_mps
        drops = 0 if axis is None else axis.n_dr_better + int(axis.stopped)
        if self._t_offset_s is not None:
            self._return_mps *= math.exp(-max(t_s - self._t_offset_s, 0.0) / RETURN_TIME_S)
            running = filter_offset_mps is not None
            if drops != self._drops or running != self._running:
                # the filter set its offset back (a stop, rule 5), or stopped or resumed
                # running (a second axis isolated, then not): the active estimate keeps
                # what it published and returns from there
                self._return_mps += self._filter_offset_mps - target
        self._t_offset_s = t_s
        self._drops = drops
        self._running = filter_offset_mps is not None
        self._filter_offset_mps = target
        return target + self._return_mps

    def lost_axis(self, v_dr_mps: float) -> AidedState:
        """(v, σ, aided, why) of the lost axis, given its dead-reckoned value now."""
        assert self._axis is not None
        st = self._axis.state()
        return AidedState(v_dr_mps + st.v_mps, st.sigma_mps, st.aided, st.why)


def _e(e_flat: list[float]) -> np.ndarray:
    return np.asarray(e_flat, dtype=np.float64).reshape(3, 3)
