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
with the dead reckoning: docs/observer.md); when one fires it stops, δ goes back to 0 and
the ``aided`` estimate *is* the bank's dead reckoning, the ``active`` one.

With a channel map (``[estimation.aero_control]``, :class:`~glmav_observer.estimation.aero.
control.ControlMapping`), the vehicle's latest ``SERVO_OUTPUT_RAW`` is held here and its
cyclic regressors (C1) enter the model: on the first usable one the model is replaced by one
with the control term (:attr:`DragModelConfig.control`; nothing learnt is lost that
early); a vehicle that never sends it keeps the drag model alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from glmav_observer.estimation.aero import (
    AidedAxis,
    AidedAxisConfig,
    AidedState,
    DragModel,
    DragModelConfig,
)
from glmav_observer.estimation.aero.control import ControlMapping

Vec3 = tuple[float, float, float]


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
        self.axis_config = axis_config
        self.sigma_handover_mps = sigma_handover_mps
        self._axis: AidedAxis | None = None
        self.control = control
        #: the latest cyclic regressors (ρ_x, ρ_y) and their vehicle time
        self._rho: tuple[float, float] | None = None
        self._t_rho_s = 0.0

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
        self, t_s: float, f_mean_body_mps2: Vec3, e_flat: list[float], v_ned_mps: Vec3
    ) -> None:
        """A healthy measurement (every axis measured and vetted by the FDI)."""
        self.model.learn(t_s, f_mean_body_mps2, _e(e_flat), v_ned_mps, self._control_at(t_s))

    def start(self, t_s: float, lost_idx: int) -> None:
        """Axis ``lost_idx`` is lost at ``t_s``: the offset starts at 0, σ the hand-over's."""
        self._axis = AidedAxis(lost_idx, 0.0, self.sigma_handover_mps, t_s, self.axis_config)

    def stop(self) -> None:
        self._axis = None

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

    def lost_axis(self, v_dr_mps: float) -> AidedState:
        """(v, σ, aided, why) of the lost axis, given its dead-reckoned value now."""
        assert self._axis is not None
        st = self._axis.state()
        return AidedState(v_dr_mps + st.v_mps, st.sigma_mps, st.aided, st.why)


def _e(e_flat: list[float]) -> np.ndarray:
    return np.asarray(e_flat, dtype=np.float64).reshape(3, 3)
