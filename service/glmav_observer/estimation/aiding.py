"""The lost axis aided by the learnt drag model: the ``aided`` configuration (issue 13).

While every axis is healthy and armed, the drag model (:class:`~glmav_observer.
estimation.aero.DragModel`) learns from each velocity measurement: the body-frame specific
force averaged over the interval since the previous one, E and the measured velocity.
When an axis is isolated, the hand-over configuration dead-reckons it (the bank,
:mod:`~glmav_observer.estimation.selection`); the ``aided`` estimate is that configuration
with its lost axis corrected by a one-state filter (:class:`~glmav_observer.estimation.
aero.AidedAxis`) on the *offset* δ between the aided and the dead-reckoned value:

    δ̇ = noise (the bank already integrates the acceleration: one propagation, not two),
    z = pseudo-measurement − dead-reckoned value,  v_aided = v_dr + δ,

started at δ = 0 with the hand-over's σ. The pseudo-measurement comes from the model with
the two measured axes (:meth:`DragModel.pseudo_measurement`: None when the model's own
tests fail, the axis is not observable at this attitude or not validated); the filter gates
it at 5σ, and after a run of rejections or when the model calls itself broken it stops for
good and falls back to its dead reckoning, here the offset 0: the plain dead reckoning.
So the aided estimate is the dead reckoning unless the model is trusted, and its σ is the
filter's (the dead reckoning's growth while no update is accepted).
"""

from __future__ import annotations

import math

import numpy as np

from glmav_observer.estimation.aero import (
    AidedAxis,
    AidedAxisConfig,
    DragModel,
    DragModelConfig,
    PseudoMeasurement,
)

Vec3 = tuple[float, float, float]


class LostAxisAiding:
    """The drag model of one vehicle and, while an axis is lost, its offset filter."""

    def __init__(
        self,
        sigma_handover_mps: float,
        model_config: DragModelConfig | None = None,
        axis_config: AidedAxisConfig | None = None,
    ) -> None:
        self.model = DragModel(model_config)
        self.axis_config = axis_config
        self.sigma_handover_mps = sigma_handover_mps
        self._offset: AidedAxis | None = None

    @property
    def lost_idx(self) -> int | None:
        return None if self._offset is None else self._offset.lost_axis

    def learn(
        self, t_s: float, f_mean_body_mps2: Vec3, e_flat: list[float], v_ned_mps: Vec3
    ) -> None:
        """A healthy measurement (every axis measured and vetted by the FDI)."""
        self.model.learn(t_s, f_mean_body_mps2, _e(e_flat), v_ned_mps)

    def start(self, t_s: float, lost_idx: int) -> None:
        """An axis is lost at ``t_s``: the offset filter starts at 0 with the hand-over σ."""
        self._offset = AidedAxis(lost_idx, 0.0, self.sigma_handover_mps, t_s, self.axis_config)

    def stop(self) -> None:
        self._offset = None

    def propagate(self, dt_s: float) -> None:
        """The offset's variance grows over a step (its mean does not: the bank moves v_dr)."""
        if self._offset is not None:
            self._offset.propagate(dt_s, 0.0)

    def update(
        self, f_mean_body_mps2: Vec3, e_flat: list[float], v_meas_ned_mps: Vec3, v_dr_mps: float
    ) -> None:
        """A measurement while the axis is lost: its two measured axes, the dead-reckoned
        value of the lost one (``v_dr_mps``) at the same time."""
        off = self._offset
        if off is None or not math.isfinite(v_dr_mps):
            return
        pm = self.model.pseudo_measurement(
            f_mean_body_mps2, _e(e_flat), v_meas_ned_mps, off.lost_axis
        )
        if pm is not None:
            pm = PseudoMeasurement(pm.v_mps - v_dr_mps, pm.sigma_mps, pm.sigma_model_mps)
        off.update(pm, self.model.broken)

    def lost_axis(self, v_dr_mps: float) -> tuple[float, float, bool]:
        """(v, σ, aided) of the lost axis given its dead-reckoned value now."""
        off = self._offset
        assert off is not None
        st = off.state()
        return v_dr_mps + st.v_mps, st.sigma_mps, st.aided


def _e(e_flat: list[float]) -> np.ndarray:
    return np.asarray(e_flat, dtype=np.float64).reshape(3, 3)
